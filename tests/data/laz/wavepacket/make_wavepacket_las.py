#!/usr/bin/env python3
"""Writes deterministic uncompressed LAS files with waveform packets (point formats 4, 5, 9, 10).

usage: make_wavepacket_las.py OUTDIR [NUM_POINTS]   (default 650 points per file)

Cases (NAME.las, see CASES): pf4-1.3, pf5-1.3 (LAS 1.3), pf9-1.4, pf10-1.4 (LAS 1.4), the same
four with 3 extra bytes per point (suffix -eb3, Extra Bytes VLR: uint8 "amplitude", int16
"deviation"), and pf10-1.4-eb3-v4 (other seed; meant to be compressed with item version 4).

Pulses of 1..5 returns (1..7 for 9/10) share GPS time, waveform offset, packet size and the
x(t)/y(t)/z(t) ray; the return point location grows with the return number.  Waveform offsets
advance by the previous packet size per pulse, sometimes jump (32-bit gaps, > 2^32 jumps (one at pulse 150),
a few backwards jumps), descriptor index is mostly 1, sometimes 2 (other packet size) or 0 (no
waveform).  Point formats 9/10 use scanner channels 0..3 (two interleaved channels most of the
time, occasionally a third/fourth one) so that LASzip's per-channel contexts are exercised.
Global encoding bit 2 (waveform data in external .wdp file) is set; no .wdp file is written.
Only the Python standard library is used; the output depends only on the seed.
"""
import math, os, random, struct, sys

SCALE = (0.001, 0.001, 0.001)
OFFSET = (500000.0, 5700000.0, 0.0)
WKT = (b'PROJCS["ETRS89 / UTM zone 32N",GEOGCS["ETRS89",DATUM["European_Terrestrial_Reference_System_1989",'
       b'SPHEROID["GRS 1980",6378137,298.257222101]],PRIMEM["Greenwich",0],UNIT["degree",0.0174532925199433]],'
       b'PROJECTION["Transverse_Mercator"],PARAMETER["latitude_of_origin",0],PARAMETER["central_meridian",9],'
       b'PARAMETER["scale_factor",0.9996],PARAMETER["false_easting",500000],PARAMETER["false_northing",0],'
       b'UNIT["metre",1],AUTHORITY["EPSG","25832"]]\0')
# wave packet descriptors: index -> (bits per sample, compression, samples, spacing ps, gain, offset)
DESCRIPTORS = {1: (8, 0, 256, 1000, 0.0078125, -16.0), 2: (16, 0, 160, 500, 0.001, 0.0)}


def packet_bytes(idx):
    b, _, n, _, _, _ = DESCRIPTORS[idx]
    return n * b // 8


def vlr(user, rid, data, desc=b""):
    v = bytearray(54)
    v[2:2 + len(user)] = user
    struct.pack_into("<HH", v, 18, rid, len(data))
    v[22:22 + len(desc)] = desc[:32]
    return bytes(v) + data


def extra_bytes_vlr():
    def desc(data_type, name, text):
        d = bytearray(192)
        d[2] = data_type          # 1 = unsigned char, 4 = short
        d[3] = 0                  # options: no no_data/min/max/scale/offset
        d[4:4 + len(name)] = name
        d[160:160 + len(text)] = text
        return bytes(d)
    return vlr(b"LASF_Spec", 4, desc(1, b"amplitude", b"echo amplitude (dB*4)") +
               desc(4, b"deviation", b"echo shape deviation"), b"Extra Bytes")


def make_points(fmt, n, rng):
    """Returns a list of dicts, one per point."""
    ext = fmt >= 6
    max_ret = 7 if ext else 5
    pts = []
    x, y, z = 1250.0, 3400.0, 310.0          # metres relative to OFFSET
    gps = 387654.125 if not ext else 1.3e8 + 0.5   # GPS week time / adjusted standard GPS time
    offset = 4096                             # byte offset into the .wdp file
    last_size = 0
    angle = -18.0
    sweep = 0.35
    psid = 17
    scan_dir = 1
    channels = [0, 1]
    chan_i = 0
    pulse = 0
    r, g, b, nir = 22000, 24000, 20000, 30000
    while len(pts) < n:
        pulse += 1
        # scan line sweep
        angle += sweep
        edge = 0
        if abs(angle) > 19.5:
            sweep = -sweep
            scan_dir ^= 1
            edge = 1
        if pulse % 150 == 0:
            psid += 1                         # new flight line
            gps += 95.0
        gps += 1.0 / 150000.0 * (1 + (rng.random() < 0.05) * rng.randint(1, 40))
        x += 0.18 * math.cos(pulse / 90.0) + rng.gauss(0, 0.05)
        y += 0.21 + rng.gauss(0, 0.05)
        z += rng.gauss(0, 0.25)
        # scanner channel (formats 9/10)
        if ext:
            if rng.random() < 0.02:
                channels = rng.sample([0, 1, 2, 3], 2)
            chan_i ^= 1
            chan = channels[chan_i] if rng.random() > 0.03 else rng.randint(0, 3)
        else:
            chan = 0
        nret = min(max_ret, 1 + int(rng.expovariate(0.9)))
        # waveform packet of this pulse
        u = rng.random()
        if u < 0.02:
            wpi = 0
        elif u < 0.12:
            wpi = 2
        else:
            wpi = 1
        if wpi == 0:
            w_off, w_size = 0, 0
        else:
            offset += last_size
            v = rng.random()
            if pulse == 150:
                offset += (1 << 32) + 4096                           # one sure 64-bit jump per file
            elif v < 0.01:
                offset += rng.randint(1, 3_000_000)                  # gap, 32-bit difference
            elif v < 0.012:
                offset += (1 << 33) + rng.randint(0, 1 << 20)        # 64-bit jump
            elif v < 0.016 and offset > 100000:
                offset -= rng.randint(1, 50000)                      # backwards (re-used samples)
            w_size = packet_bytes(wpi)
            if rng.random() < 0.03:
                w_size -= 2 * rng.randint(1, 40)                     # truncated record
            w_off = offset
            last_size = w_size
        theta = math.radians(angle)
        xt = float(struct.unpack("<f", struct.pack("<f", 1.5e-4 * math.sin(theta) + 2e-6 * math.cos(pulse / 50.0)))[0])
        yt = float(struct.unpack("<f", struct.pack("<f", 1.2e-5 * math.cos(pulse / 333.0)))[0])
        zt = float(struct.unpack("<f", struct.pack("<f", -1.4989e-4 * math.cos(theta)))[0])
        loc0 = 20000.0 + rng.uniform(0, 4000)
        for k in range(1, nret + 1):
            if len(pts) >= n:
                break
            loc = loc0 + (k - 1) * rng.uniform(800, 9000)
            d = loc - loc0                    # along the ray: P = P0 + d * (x(t), y(t), z(t))
            last = k == nret
            if last and rng.random() < 0.7:
                cls = 2
            elif nret > 1:
                cls = rng.choice([3, 4, 5, 5, 5, 1])
            else:
                cls = rng.choice([2, 6, 6, 1, 9])
            if ext and rng.random() < 0.01:
                cls = rng.choice([64, 65, 150])
            r = min(65535, max(0, r + rng.randint(-900, 900)))
            g = min(65535, max(0, g + rng.randint(-900, 900)))
            b = min(65535, max(0, b + rng.randint(-900, 900)))
            nir = min(65535, max(0, nir + rng.randint(-1200, 1200)))
            pts.append(dict(
                x=x + d * xt + rng.gauss(0, 0.01), y=y + d * yt + rng.gauss(0, 0.01), z=z + d * zt + rng.gauss(0, 0.01),
                intensity=max(0, min(65535, int(rng.gauss(900 / k, 150)))),
                ret=k, nret=nret, scan_dir=scan_dir, edge=edge if k == 1 else 0,
                cls=cls, flags=(1 if rng.random() < 0.01 else 0) | (8 if ext and psid % 2 and rng.random() < 0.3 else 0),
                chan=chan, angle=angle, user=(pulse * 7 + k) & 0xFF if rng.random() < 0.5 else 0,
                psid=psid, gps=gps,
                rgb=(r, g, b), nir=nir,
                wpi=wpi, w_off=w_off, w_size=w_size,
                w_loc=(loc if wpi else 0.0), xt=(xt if wpi else 0.0), yt=(yt if wpi else 0.0), zt=(zt if wpi else 0.0),
                eb=(max(0, min(255, int(rng.gauss(120 / k, 20)))), rng.randint(-300, 300))))
    return pts


def record(fmt, p, rl):
    q = [round(v / s) for v, s in zip((p["x"], p["y"], p["z"]), SCALE)]  # coordinates are relative to OFFSET
    out = bytearray(struct.pack("<iiiH", q[0], q[1], q[2], p["intensity"]))
    if fmt >= 6:
        out += bytes([(p["ret"] & 15) | ((p["nret"] & 15) << 4),
                      (p["flags"] & 15) | ((p["chan"] & 3) << 4) | (p["scan_dir"] << 6) | (p["edge"] << 7),
                      p["cls"], p["user"]])
        out += struct.pack("<hHd", int(round(p["angle"] / 0.006)), p["psid"], p["gps"])
        if fmt == 10:
            out += struct.pack("<HHHH", *p["rgb"], p["nir"])
    else:
        out += bytes([(p["ret"] & 7) | ((p["nret"] & 7) << 3) | (p["scan_dir"] << 6) | (p["edge"] << 7),
                      (p["cls"] & 31) | ((p["flags"] & 7) << 5)])
        out += struct.pack("<bBHd", int(round(p["angle"])), p["user"], p["psid"], p["gps"])
        if fmt == 5:
            out += struct.pack("<HHH", *p["rgb"])
    out += struct.pack("<BQIffff", p["wpi"], p["w_off"], p["w_size"], p["w_loc"], p["xt"], p["yt"], p["zt"])
    if len(out) < rl:
        out += struct.pack("<Bh", *p["eb"])
    assert len(out) == rl, (fmt, len(out), rl)
    return bytes(out)


BASE = {4: 57, 5: 63, 9: 59, 10: 67}


def write_las(path, fmt, n, extra, seed):
    rng = random.Random(seed)
    minor = 4 if fmt >= 6 else 3
    rl = BASE[fmt] + (3 if extra else 0)
    pts = make_points(fmt, n, rng)
    vlrs = b""
    nvlr = 0
    if minor == 4:
        vlrs += vlr(b"LASF_Projection", 2112, WKT, b"OGC WKT"); nvlr += 1
    for idx, (bps, comp, ns, sp, gain, off) in DESCRIPTORS.items():
        vlrs += vlr(b"LASF_Spec", 99 + idx, struct.pack("<BBIIdd", bps, comp, ns, sp, gain, off),
                    b"waveform packet descriptor"); nvlr += 1
    if extra:
        vlrs += extra_bytes_vlr(); nvlr += 1
    hs = 375 if minor == 4 else 235
    h = bytearray(hs)
    h[0:4] = b"LASF"
    struct.pack_into("<HH", h, 4, 0, 0x4 | (0x10 if minor == 4 else 0) | (0x1 if minor == 4 else 0))
    h[24], h[25] = 1, minor
    h[26:26 + 9] = b"cityforge"
    h[58:58 + 22] = b"make_wavepacket_las.py"
    by_ret = [0] * 15
    for p in pts:
        by_ret[p["ret"] - 1] += 1
    legacy = minor < 4
    struct.pack_into("<HHHIIBHI", h, 90, 123, 2026, hs, hs + len(vlrs), nvlr, fmt, rl, len(pts) if legacy else 0)
    struct.pack_into("<5I", h, 111, *(by_ret[:5] if legacy else [0] * 5))
    struct.pack_into("<3d3d", h, 131, *SCALE, *OFFSET)
    recs = [record(fmt, p, rl) for p in pts]
    xs = [struct.unpack_from("<iii", r, 0) for r in recs]
    for k in range(3):
        mx = max(v[k] for v in xs) * SCALE[k] + OFFSET[k]
        mn = min(v[k] for v in xs) * SCALE[k] + OFFSET[k]
        struct.pack_into("<dd", h, 179 + 16 * k, mx, mn)
    struct.pack_into("<Q", h, 227, 0)  # start of waveform data packet record: external .wdp
    if minor == 4:
        struct.pack_into("<QIQ15Q", h, 235, 0, 0, len(pts), *by_ret)
    with open(path, "wb") as f:
        f.write(bytes(h) + vlrs + b"".join(recs))
    return len(pts), rl


CASES = [  # name, point format, extra bytes, seed
    ("pf4-1.3", 4, False, 0x5781), ("pf4-1.3-eb3", 4, True, 0x5782),
    ("pf5-1.3", 5, False, 0x5791), ("pf5-1.3-eb3", 5, True, 0x5792),
    ("pf9-1.4", 9, False, 0x57d1), ("pf9-1.4-eb3", 9, True, 0x57d2),
    ("pf10-1.4", 10, False, 0x57e1), ("pf10-1.4-eb3", 10, True, 0x57e2),
    ("pf10-1.4-eb3-v4", 10, True, 0x57e4),  # compressed with item version 4
]


def main():
    outdir = sys.argv[1]
    n = int(sys.argv[2]) if len(sys.argv) > 2 else 650
    os.makedirs(outdir, exist_ok=True)
    for name, fmt, extra, seed in CASES:
        cnt, rl = write_las(os.path.join(outdir, name + ".las"), fmt, n, extra, seed)
        print(name, cnt, rl)


if __name__ == "__main__":
    main()
