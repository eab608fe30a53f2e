#!/usr/bin/env python3
"""Prints the last `cargo bench --bench pipeline` results as a markdown table.

Reads target/criterion/<group>/<file>/new/{benchmark,estimates,sample}.json and gives,
per stage and corpus file, throughput in MB/s (10^6 bytes of *input* per second):

- "typical": from criterion's slope estimate (its headline figure), or the mean;
- "best sample": from the fastest of the samples, the least disturbed by other
  processes on a loaded machine.

Usage: python3 scripts/criterion-table.py [TARGET_DIR]   (default: target)
"""
import json
import sys
from pathlib import Path

GROUPS = ["lex", "parse", "lower", "emit", "pipeline"]


def main() -> int:
    root = Path(sys.argv[1] if len(sys.argv) > 1 else "target") / "criterion"
    if not root.is_dir():
        print(f"no criterion results under {root}; run `cargo bench --bench pipeline` first", file=sys.stderr)
        return 1
    rows = {}
    files = []
    for group in GROUPS:
        gdir = root / group
        if not gdir.is_dir():
            continue
        for bench in sorted(gdir.iterdir()):
            new = bench / "new"
            if not (new / "benchmark.json").is_file():
                continue
            meta = json.loads((new / "benchmark.json").read_text())
            est = json.loads((new / "estimates.json").read_text())
            sample = json.loads((new / "sample.json").read_text())
            nbytes = meta["throughput"].get("Bytes") or meta["throughput"].get("BytesDecimal")
            typical_ns = (est.get("slope") or est["mean"])["point_estimate"]
            best_ns = min(t / i for t, i in zip(sample["times"], sample["iters"]))
            name = meta["function_id"]
            if name not in files:
                files.append(name)
            rows[(group, name)] = (nbytes, typical_ns, best_ns)
    print("| stage | " + " | ".join(f"`{f}`" for f in files) + " |")
    print("| --- |" + " ---: |" * len(files))
    for group in GROUPS:
        cells = []
        for f in files:
            if (group, f) not in rows:
                cells.append("n/a")
                continue
            nbytes, typical, best = rows[(group, f)]
            cells.append(f"{nbytes / typical * 1e3:.1f} (best {nbytes / best * 1e3:.1f})")
        if any(c != "n/a" for c in cells):
            print(f"| {group} | " + " | ".join(cells) + " |")
    print()
    print("MB/s of input (10^6 bytes/s): criterion's typical (slope) estimate, and in brackets the fastest sample.")
    sizes = {f: rows[next(k for k in rows if k[1] == f)][0] for f in files}
    print("Input sizes: " + ", ".join(f"`{f}` {sizes[f]} bytes" for f in files) + ".")
    return 0


if __name__ == "__main__":
    sys.exit(main())
