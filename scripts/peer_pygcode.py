#!/usr/bin/env python3
"""Peer benchmark: parse-only run of a G-code file with pygcode.

Iterates the file's lines, builds a pygcode ``Line`` for each (which tokenises
the words and groups them into G-codes and modal parameters) and counts the
results so the work is not skipped. Lines pygcode rejects (e.g. PrusaSlicer's
``M862.3 P "MINI"``) are counted as errors and parsing goes on.

Used by scripts/bench-peers.sh.  Usage: peer_pygcode.py FILE
"""
import sys

from pygcode import Line


def main() -> int:
    if len(sys.argv) != 2:
        print("usage: peer_pygcode.py FILE", file=sys.stderr)
        return 2
    lines = words = gcodes = comments = errors = 0
    first_error = None
    with open(sys.argv[1], "r", encoding="utf-8", errors="replace") as f:
        for lineno, text in enumerate(f, 1):
            lines += 1
            try:
                line = Line(text)
            except Exception as e:  # pygcode raises on words it cannot read
                errors += 1
                if first_error is None:
                    first_error = f"line {lineno}: {type(e).__name__}: {e}"
                continue
            words += len(line.block.words)
            gcodes += len(line.block.gcodes)
            if line.comment is not None:
                comments += 1
    msg = (f"pygcode: lines={lines} words={words} gcodes={gcodes} "
           f"comments={comments} errors={errors}")
    if first_error:
        msg += f" (first: {first_error})"
    print(msg)
    return 0


if __name__ == "__main__":
    sys.exit(main())
