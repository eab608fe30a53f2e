#!/usr/bin/env python3
"""Generates an APT CL file with N GOTO points (default 1,000,000) whose tool axis varies.

Usage: python3 scripts/gen-cl.py [N] > target/bench-data/five_axis_1M.cl

The path is a 5-axis swarf-like spiral around the C axis: the tip climbs a helix on a
cylinder of radius 40 mm while the tool axis leans outwards between 5 and 60 degrees
from vertical and turns with the path, so C winds up over many turns and A varies
continuously (every IK branch decision, unwrap and densify are exercised). Deterministic.
"""
import math
import sys


def main() -> None:
    n = int(sys.argv[1]) if len(sys.argv) > 1 else 1_000_000
    out = sys.stdout
    w = out.write
    w("PARTNO/NCPOST BENCH 5-AXIS SPIRAL\n")
    w("UNITS/MM\nMULTAX/ON\nLOADTL/1\nSPINDL/12000,CLW\n")
    w("RAPID\nGOTO/40.000000,0.000000,60.000000,0.000000000,0.000000000,1.000000000\n")
    w("FEDRAT/MMPM,1200.0\n")
    turns = max(1, n // 3600)
    lines = []
    for i in range(n):
        s = i / n
        phi = 2.0 * math.pi * turns * s
        r = 40.0 + 5.0 * math.sin(7.0 * phi)
        x = r * math.cos(phi)
        y = r * math.sin(phi)
        z = 40.0 - 30.0 * s
        tilt = math.radians(32.5 + 27.5 * math.sin(3.0 * phi + 11.0 * s))
        lean = phi + 0.3 * math.sin(5.0 * phi)
        i_ = math.sin(tilt) * math.cos(lean)
        j_ = math.sin(tilt) * math.sin(lean)
        k_ = math.cos(tilt)
        lines.append(f"GOTO/{x:.6f},{y:.6f},{z:.6f},{i_:.9f},{j_:.9f},{k_:.9f}\n")
        if len(lines) >= 4096:
            w("".join(lines))
            lines.clear()
    w("".join(lines))
    w("RAPID\nGOTO/0.000000,0.000000,100.000000,0.000000000,0.000000000,1.000000000\n")
    w("SPINDL/OFF\nEND\nFINI\n")


if __name__ == "__main__":
    main()
