#!/usr/bin/env python3
"""An independent reference for split_las_into_windows (Python standard
library only: none of cityforge's LAS code).

    python3 las_window_oracle.py SOURCE.las WINDOWS.json OUT_0.las OUT_1.las ...

WINDOWS.json holds [[min_x, min_y, max_x, max_y], ...] (file units; a point is
in a window when min_x <= x < max_x and min_y <= y < max_y, x = X * scale +
offset). The source's points are screened by its header's bounds as LAS
readers do (beyond them by more than one scale quantum: dropped, unless the
bounds are unusable). Each output must hold exactly the source's points of its
window, in file order, on the source's integer grid (same scale and offset):
X, Y, Z, intensity, return number, number of returns, classification, GPS time
and colour where both formats have them. Exit 0 when every output matches,
1 with the first difference otherwise.
"""
import json
import math
import struct
import sys


def header(data, path):
    if data[:4] != b"LASF":
        raise SystemExit(f"{path}: not a LAS file")
    minor = data[25]
    offset_to_points = struct.unpack_from("<I", data, 96)[0]
    fmt = data[104] & 0x3F
    length = struct.unpack_from("<H", data, 105)[0]
    count = struct.unpack_from("<I", data, 107)[0]
    if minor >= 4 and count == 0:
        count = struct.unpack_from("<Q", data, 247)[0]
    scale = struct.unpack_from("<3d", data, 131)
    offset = struct.unpack_from("<3d", data, 155)
    mx, nx, my, ny, mz, nz = struct.unpack_from("<6d", data, 179)
    return {"fmt": fmt, "length": length, "count": count, "at": offset_to_points, "scale": scale, "offset": offset,
            "min": (nx, ny, nz), "max": (mx, my, mz)}


# Record layouts: (gps time offset or None, rgb offset or None); formats 0-5
# keep return bits and class in bytes 14-15, 6-10 in bytes 14 and 16.
LEGACY = {0: (None, None), 1: (20, None), 2: (None, 20), 3: (20, 28), 4: (20, None), 5: (20, 28)}
EXTENDED = {6: (22, None), 7: (22, 30), 8: (22, 30), 9: (22, None), 10: (22, 30)}


def points(path):
    with open(path, "rb") as f:
        data = f.read()
    h = header(data, path)
    fmt, length = h["fmt"], h["length"]
    gps_at, rgb_at = LEGACY.get(fmt) or EXTENDED[fmt]
    out = []
    for i in range(h["count"]):
        base = h["at"] + i * length
        X, Y, Z, intensity = struct.unpack_from("<iiiH", data, base)
        if fmt <= 5:
            bits = data[base + 14]
            ret, nret, cls = bits & 7, (bits >> 3) & 7, data[base + 15] & 0x1F
        else:
            bits = data[base + 14]
            ret, nret, cls = bits & 15, bits >> 4, data[base + 16]
        gps = struct.unpack_from("<d", data, base + gps_at)[0] if gps_at is not None else None
        rgb = struct.unpack_from("<3H", data, base + rgb_at) if rgb_at is not None else None
        out.append((X, Y, Z, intensity, ret, nret, cls, gps, rgb))
    return h, out


def main():
    source, windows_path, outputs = sys.argv[1], sys.argv[2], sys.argv[3:]
    with open(windows_path) as f:
        windows = json.load(f)
    if len(windows) != len(outputs):
        raise SystemExit(f"{len(windows)} windows but {len(outputs)} outputs")
    h, src = points(source)
    sx, sy, sz = h["scale"]
    ox, oy, oz = h["offset"]
    usable = all(math.isfinite(h["min"][k]) and math.isfinite(h["max"][k]) and h["min"][k] <= h["max"][k] for k in range(3)) and any(
        h["min"][k] != 0.0 or h["max"][k] != 0.0 for k in range(3))
    tol = [h["scale"][k] + 1e-9 * max(abs(h["min"][k]), abs(h["max"][k])) for k in range(3)]
    expected = [[] for _ in windows]
    for p in src:
        x, y, z = p[0] * sx + ox, p[1] * sy + oy, p[2] * sz + oz
        if usable and any(v < h["min"][k] - tol[k] or v > h["max"][k] + tol[k] for k, v in enumerate((x, y, z))):
            continue
        for w, (x0, y0, x1, y1) in enumerate(windows):
            if x0 <= x < x1 and y0 <= y < y1:  # a NaN edge holds no point
                expected[w].append(p)
    for w, path in enumerate(outputs):
        oh, got = points(path)
        if oh["scale"] != h["scale"] or oh["offset"] != h["offset"]:
            print(f"{path}: scale/offset {oh['scale']} {oh['offset']}, source {h['scale']} {h['offset']}")
            return 1
        # The header readers rely on: the legacy count (the count for
        # formats 0-5; 0 for 6+, which keep no legacy compatibility: LAS 1.4
        # R15), the 64-bit count of LAS 1.4, and bounds that enclose every
        # point (within one scale quantum).
        with open(path, "rb") as f:
            raw = f.read(375)
        legacy = struct.unpack_from("<I", raw, 107)[0]
        if legacy != (0 if oh["fmt"] >= 6 else len(got)):
            print(f"{path}: legacy point count {legacy} for {len(got)} points of format {oh['fmt']}")
            return 1
        if raw[25] >= 4 and struct.unpack_from("<Q", raw, 247)[0] != len(got):
            print(f"{path}: point count {struct.unpack_from('<Q', raw, 247)[0]} for {len(got)} points")
            return 1
        for p in got:
            for k, v in enumerate((p[0] * sx + ox, p[1] * sy + oy, p[2] * sz + oz)):
                if v < oh["min"][k] - h["scale"][k] or v > oh["max"][k] + h["scale"][k]:
                    print(f"{path}: point {p[:3]} outside the header's bounds {oh['min']} {oh['max']}")
                    return 1
        if len(got) != len(expected[w]):
            print(f"{path}: {len(got)} points, expected {len(expected[w])}")
            return 1
        for i, (a, b) in enumerate(zip(got, expected[w])):
            # GPS time and colour compared where both records hold them.
            a2 = a[:7] + ((a[7],) if a[7] is not None and b[7] is not None else ()) + ((a[8],) if a[8] is not None and b[8] is not None else ())
            b2 = b[:7] + ((b[7],) if a[7] is not None and b[7] is not None else ()) + ((b[8],) if a[8] is not None and b[8] is not None else ())
            if a2 != b2:
                print(f"{path}: point {i} is {a}, expected {b}")
                return 1
    return 0


if __name__ == "__main__":
    sys.exit(main())
