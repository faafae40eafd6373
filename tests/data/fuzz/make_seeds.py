#!/usr/bin/env python3
"""Writes the fuzz seeds of tests/fuzz/test_fuzz_inputs.cpp into seeds/ (small, deterministic).

LAS 1.2 point format 1 (GeoTIFF keys), LAS 1.4 point format 7 (WKT VLR and a WKT EVLR),
binary and ASCII PLY, XYZ/CSV text, GeoJSON footprints (a hole, a multipolygon)."""
import math, os, struct

here = os.path.join(os.path.dirname(os.path.abspath(__file__)), "seeds")
os.makedirs(here, exist_ok=True)
pts = [(500000 + 0.5 * i + 0.25 * (j % 2), 4400000 + 0.5 * j, 10 + 3 * math.sin(i) * (1 if (i + j) % 3 else 0), (i * 37 + j) % 4096, 2 if (i + j) % 3 == 0 else 6)
       for i in range(6) for j in range(6)]
wkt = b'PROJCS["WGS 84 / UTM zone 50N",GEOGCS["WGS 84",DATUM["WGS_1984",SPHEROID["WGS 84",6378137,298.257223563]],PRIMEM["Greenwich",0],UNIT["degree",0.0174532925199433]],PROJECTION["Transverse_Mercator"],PARAMETER["latitude_of_origin",0],PARAMETER["central_meridian",117],PARAMETER["scale_factor",0.9996],PARAMETER["false_easting",500000],PARAMETER["false_northing",0],UNIT["metre",1],AUTHORITY["EPSG","32650"]]\0'
scale, offset = (0.01, 0.01, 0.01), (500000.0, 4400000.0, 0.0)

def bounds():
    return [max(p[k] for p in pts) for k in range(3)], [min(p[k] for p in pts) for k in range(3)]

def las(minor, fmt, rl, vlrs, evlrs=b"", n_evlr=0):
    hs = 375 if minor >= 4 else 227
    h = bytearray(hs)
    h[0:4] = b"LASF"
    struct.pack_into("<H", h, 6, 0x10 if minor >= 4 else 0)
    h[24], h[25] = 1, minor
    h[26:35] = b"cityforge"
    h[58:68] = b"make_seeds"
    struct.pack_into("<HH", h, 90, 1, 2026)
    struct.pack_into("<HIIBHI", h, 94, hs, hs + len(vlrs), vlrs.count(b"LASF_Projection") if vlrs else 0, fmt, rl, len(pts) if minor < 4 else 0)
    for k in range(3):
        struct.pack_into("<d", h, 131 + 8 * k, scale[k])
        struct.pack_into("<d", h, 155 + 8 * k, offset[k])
    mx, mn = bounds()
    for k in range(3):
        struct.pack_into("<dd", h, 179 + 16 * k, mx[k], mn[k])
    recs = bytearray()
    for (x, y, z, inten, cls) in pts:
        r = bytearray(rl)
        struct.pack_into("<iiiH", r, 0, *(round((v - o) / s) for v, o, s in zip((x, y, z), offset, scale)), inten)
        if fmt >= 6:
            r[14] = 1 | (1 << 4); r[16] = cls
            struct.pack_into("<d", r, 22, 1000.5 + inten)
            struct.pack_into("<HHH", r, 30, inten * 16, 3000, 50000)
        else:
            r[14] = 1 | (1 << 3); r[15] = cls
            struct.pack_into("<d", r, 20, 1000.5 + inten)
        recs += r
    body = bytes(h) + vlrs + bytes(recs)
    if minor >= 4:
        b = bytearray(body)
        struct.pack_into("<QIQ", b, 235, len(body) if evlrs else 0, n_evlr, len(pts))
        body = bytes(b) + evlrs
    return body

def vlr(user, rid, data, desc=b""):
    v = bytearray(54)
    v[2:2 + len(user)] = user
    struct.pack_into("<HH", v, 18, rid, len(data))
    v[22:22 + len(desc)] = desc
    return bytes(v) + data

def evlr(user, rid, data):
    v = bytearray(60)
    v[2:2 + len(user)] = user
    struct.pack_into("<HQ", v, 18, rid, len(data))
    return bytes(v) + data

geokeys = struct.pack("<16H", 1, 1, 0, 3, 1024, 0, 1, 1, 3072, 0, 1, 32650, 1025, 0, 1, 1)
open(os.path.join(here, "f1_geokeys.las"), "wb").write(las(2, 1, 28, vlr(b"LASF_Projection", 34735, geokeys)))
open(os.path.join(here, "f7_wkt_evlr.las"), "wb").write(
    las(4, 7, 36, vlr(b"LASF_Projection", 2112, wkt, b"OGC WKT"), evlr(b"LASF_Projection", 2112, wkt), 1))

ply_head = "ply\nformat {}\ncomment seed\nelement vertex {}\nproperty {t} x\nproperty {t} y\nproperty {t} z\nproperty uchar red\nproperty uchar green\nproperty uchar blue\nproperty uchar classification\n{}end_header\n"
with open(os.path.join(here, "binary.ply"), "wb") as f:
    f.write(ply_head.format("binary_little_endian 1.0", len(pts), "element face 0\nproperty list uchar int vertex_indices\n", t="double").encode())
    for (x, y, z, i, c) in pts:
        f.write(struct.pack("<dddBBBB", x, y, z, i % 256, 100, 200, c))
with open(os.path.join(here, "binary_be_float.ply"), "wb") as f:
    f.write(ply_head.format("binary_big_endian 1.0", len(pts), "", t="float").encode())
    for (x, y, z, i, c) in pts:
        f.write(struct.pack(">fffBBBB", x - 500000, y - 4400000, z, i % 256, 100, 200, c))
with open(os.path.join(here, "ascii.ply"), "w") as f:
    f.write(ply_head.format("ascii 1.0", len(pts), "", t="float"))
    for (x, y, z, i, c) in pts:
        f.write(f"{x:.3f} {y:.3f} {z:.3f} {i % 256} 100 200 {c}\n")
with open(os.path.join(here, "header.xyz"), "w") as f:
    f.write("X,Y,Z,Intensity,Classification\n")
    for (x, y, z, i, c) in pts:
        f.write(f"{x:.3f},{y:.3f},{z:.3f},{i},{c}\n")
with open(os.path.join(here, "plain.xyz"), "w") as f:
    for (x, y, z, i, c) in pts:
        f.write(f"{x:.3f} {y:.3f} {z:.3f} {i % 256} 100 200\n")
gj = """{"type": "FeatureCollection", "name": "seed",
"crs": {"type": "name", "properties": {"name": "urn:ogc:def:crs:EPSG::32650"}},
"features": [
{"type": "Feature", "id": 1, "properties": {"id": 1, "name": "court", "h": 7.5},
 "geometry": {"type": "Polygon", "coordinates": [[[500000.2, 4400000.2], [500002.4, 4400000.2], [500002.4, 4400002.4], [500000.2, 4400002.4], [500000.2, 4400000.2]],
   [[500000.8, 4400000.8], [500000.8, 4400001.6], [500001.6, 4400001.6], [500001.6, 4400000.8], [500000.8, 4400000.8]]]}},
{"type": "Feature", "id": 2, "properties": {"id": 2, "name": "two parts", "h": null},
 "geometry": {"type": "MultiPolygon", "coordinates": [[[[500000.1, 4400002.6], [500001.0, 4400002.6], [500001.0, 4400002.9], [500000.1, 4400002.9], [500000.1, 4400002.6]]],
   [[[500001.5, 4400002.6], [500002.5, 4400002.6], [500002.0, 4400002.95], [500001.5, 4400002.6]]]]}}
]}
"""
open(os.path.join(here, "footprints.geojson"), "w").write(gj)
