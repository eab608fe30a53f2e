#!/usr/bin/env python3
"""A straightforward pure-Python post of the seed formulas (seeds/000, E-moc X5): the peer
ncpost's emoc-x5 pipeline is benchmarked against.

Usage: python3 scripts/seed_post.py INPUT.cl > OUTPUT.gcode

It does what the hand-written post described in the seed does and nothing more: for each
GOTO/x,y,z,i,j,k it computes A = acos(Tz), C = sgn(Ty) acos(Ty / sqrt(Tx^2 + Ty^2)) (the
printed C formula, kept as printed) and X, Y, Z by the seed's formulas with az = 100 mm,
tracks C against the previous angle (the seed's +-180 problem), and prints G1 lines with
the programmed feed. No densification, no feed correction, no limits, no diagnostics.
"""
import math
import sys

AZ = 100.0


def sgn(a: float) -> float:
    return 1.0 if a >= 0.0 else -1.0


def main() -> None:
    src = open(sys.argv[1], encoding="utf-8", errors="replace")
    out = sys.stdout
    w = out.write
    w("G21 G90\n")
    prev_c = 0.0
    feed = None
    rapid = False
    for line in src:
        line = line.strip()
        if line.startswith("FEDRAT/"):
            parts = [p.strip() for p in line[7:].split(",")]
            nums = [p for p in parts if p not in ("MMPM", "IPM")]
            feed = float(nums[0])
            continue
        if line.startswith("RAPID"):
            rapid = True
            continue
        if not line.startswith("GOTO/"):
            continue
        v = [float(t) for t in line[5:].split(",")]
        px, py, pz = v[0], v[1], v[2]
        tx, ty, tz = (v[3], v[4], v[5]) if len(v) >= 6 else (0.0, 0.0, 1.0)
        a = math.acos(max(-1.0, min(1.0, tz)))
        if tz != 1.0:
            c = sgn(ty) * math.acos(ty / math.sqrt(tx * tx + ty * ty))
        else:
            c = math.radians(prev_c)
        sa, ca, sc, cc = math.sin(a), math.cos(a), math.sin(c), math.cos(c)
        x = (sc * py + cc * px) / (sc * sc + cc * cc)
        den = (sa * sa + ca * ca) * sc * sc + cc * cc * sa * sa + ca * ca * cc * cc
        y = -(-(sa * sc * sc * pz) - cc * cc * sa * pz - ca * cc * py + ca * sc * px
              + (sa * sc * sc + cc * cc * sa) * AZ) / den
        z = (ca * sc * sc * pz + ca * cc * cc * pz - cc * sa * py + sa * sc * px
             + ((sa * sa + ca * ca - ca) * sc * sc + cc * cc * sa * sa
                + (ca * ca - ca) * cc * cc) * AZ) / den
        c_deg = math.degrees(c)
        # The firmware treats C as linear: keep it within 180 deg of the previous value.
        while c_deg - prev_c > 180.0:
            c_deg -= 360.0
        while c_deg - prev_c < -180.0:
            c_deg += 360.0
        prev_c = c_deg
        if rapid or feed is None:
            w(f"G0 X{x:.3f} Y{y:.3f} Z{z:.3f} A{math.degrees(a):.3f} C{c_deg:.3f}\n")
            rapid = False
        else:
            w(f"G1 X{x:.3f} Y{y:.3f} Z{z:.3f} A{math.degrees(a):.3f} C{c_deg:.3f} F{feed:.1f}\n")


if __name__ == "__main__":
    main()
