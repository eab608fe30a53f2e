#!/usr/bin/env bash
# Pieces against the fewest that hold the tolerance (benches/pieces.rs): how many blocks
# `densify` (the four 5-axis presets) and `polar-ik` (polar-printer) emit on generated
# programs, against greedy longest pieces checked by dense sampling of the deviation.
#
# Usage (from anywhere):  bash scripts/bench-pieces.sh
#
# The counts do not depend on the build, so this runs a debug build (a minute or two).
set -euo pipefail
cd "$(dirname "$0")/.."
cargo bench --quiet --profile dev --bench pieces
