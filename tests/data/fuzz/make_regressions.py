#!/usr/bin/env python3
"""Writes regressions/: small inputs that once crashed, hung or silently misread a
reader (issue #15), replayed by tests/fuzz/test_fuzz_inputs.cpp. Each is derived
from a seed (make_seeds.py) or tests/data/laz/; the comment says what it did."""
import json, os, struct

here = os.path.dirname(os.path.abspath(__file__))
seeds = os.path.join(here, "seeds")
out = os.path.join(here, "regressions")
for t in ("las", "ply", "xyz", "geojson"):
    os.makedirs(os.path.join(out, t), exist_ok=True)

def put(b, fmt, at, *v):
    b = bytearray(b)
    struct.pack_into(fmt, b, at, *v)
    return bytes(b)

def write(kind, name, data):
    open(os.path.join(out, kind, name), "wb").write(data if isinstance(data, bytes) else data.encode())

las14 = open(os.path.join(seeds, "f7_wkt_evlr.las"), "rb").read()
las12 = open(os.path.join(seeds, "f1_geokeys.las"), "rb").read()
# Hung: an EVLR length of 2^64 - 60 wrapped the read position, 0xFFFFFFFF EVLRs looped.
evlr_at = struct.unpack_from("<Q", las14, 235)[0]
write("las", "evlr_length_wraps.las", put(put(las14, "<Q", evlr_at + 20, 2**64 - 60), "<I", 243, 0xFFFFFFFF))
# Misread: 2^62 points x 36 bytes wrapped past the size check (info reported 4611686018427387904 points).
write("las", "count_2p62.las", put(las14, "<Q", 247, 2**62))
write("las", "count_wraps_to_small.las", put(las14, "<Q", 247, (2**64) // 36 + 1))
# Silent: a scale of 1e300 gave all-null heights with exit 0.
write("las", "scale_1e300.las", put(las12, "<d", 131, 1e300))
# UBSan: a WKT VLR of length 0 passed a null pointer to strnlen.
hs = struct.unpack_from("<H", las14, 94)[0]
write("las", "wkt_vlr_length_0.las", put(las14, "<H", hs + 20, 0)[:hs + 54] + las14[hs + 54:])
# Garbage records (a VLR shifting them): the ground filter built a grid of 4e8 cells.
off = struct.unpack_from("<I", las12, 96)[0]
b = las12
for k in range(0, 36, 5):
    b = put(b, "<i", off + 28 * k, 2_000_000_000 - k)
write("las", "records_outside_bounds.las", b)
# Hung: a LAZ header claiming 2^62 points of fixed chunks, no chunk table: 1.8e16 chunk entries.
laz = open(os.path.join(here, "..", "laz", "pdrf7-v4-1.4.laz"), "rb").read()
lo = struct.unpack_from("<I", laz, 96)[0]
write("las", "laz_no_table_2p62_points.laz", put(put(laz, "<Q", 247, 2**62), "<q", lo, -2))

ply = open(os.path.join(seeds, "binary.ply"), "rb").read()
head, body = ply.split(b"end_header\n", 1)
# Internal error: declared float, holding doubles ("cannot create std::vector larger than max_size()").
write("ply", "float_holding_doubles.ply", head.replace(b"double", b"float") + b"end_header\n" + body)
# Count x record length wrapped the size check.
write("ply", "count_wraps.ply", head.replace(b"element vertex 36", b"element vertex 737869762948382065") + b"end_header\n" + body)
# Silent: NaN coordinates changed outlier counts and heights.
write("ply", "nan_vertices.ply", head + b"end_header\n" + struct.pack("<ddd", float("nan"), 1, 2) + body[24:])

xyz = open(os.path.join(seeds, "plain.xyz")).read().splitlines(True)
write("xyz", "nan_line.xyz", "".join(xyz[:10] + ["nan nan nan 0 0 0\n"] + xyz[10:]))
write("xyz", "inf_only.xyz", "inf 1 2\n-inf 1 2\n")
# "grid too large" / a 4e8-cell ground grid for 1e308 or far points.
write("xyz", "coordinates_1e308.xyz", "".join(xyz + ["1e308 1e308 1 0 0 0\n", "-1e308 -1e308 1 0 0 0\n"]))
write("xyz", "far_points.xyz", "".join(xyz + ["4e7 4e7 1 0 0 0\n"]))
# Heap overflow under ASan: a line with fewer columns than the first read past the row.
write("xyz", "short_line.xyz", "500000 4400000 10 7\n500001 4400001\n")

g = json.load(open(os.path.join(seeds, "footprints.geojson")))
# Crash (segfault in heights) and "bad numeric conversion" (audit): coordinates of 1e300.
e = json.loads(json.dumps(g))
e["features"][0]["geometry"]["coordinates"][0][1] = [1e300, 4400000.2]
write("geojson", "coordinate_1e300.geojson", json.dumps(e))
# Out of memory in heights and roofs: a footprint 1e9 m wide.
h = json.loads(json.dumps(g))
h["features"][0]["geometry"] = {"type": "Polygon", "coordinates": [[[0, 0], [1e9, 0], [1e9, 1e9], [0, 1e9], [0, 0]]]}
write("geojson", "footprint_1e9_m.geojson", json.dumps(h))
