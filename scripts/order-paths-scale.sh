#!/usr/bin/env bash
# Scaling check of `order-paths` (issue 21): one segment of N cut groups (default 200000)
# scattered over a 300 mm board, and the same groups on one vertical line (every end at
# the same X), ordered by the release binary. Prints the time of each; fails when one
# takes longer than LIMIT seconds (default 60, what the quadratic search took before).
# The unit test `passes::order_paths::tour::tests::work_grows_as_n_log_n` checks the
# growth by counting work; this script shows the time on a real run.
#
# Usage (from anywhere):  bash scripts/order-paths-scale.sh [N] [LIMIT]
set -euo pipefail
cd "$(dirname "$0")/.."
N=${1:-200000}
LIMIT=${2:-60}
# The build golden.sh makes (no LTO): quicker, and the timing differs little.
export CARGO_PROFILE_RELEASE_LTO=false CARGO_PROFILE_RELEASE_CODEGEN_UNITS=16
cargo build --release --quiet
BIN=${CARGO_TARGET_DIR:-target}/release/ncpost
DIR=$(mktemp -d)
trap 'rm -rf "$DIR"' EXIT
status=0
for layout in scattered column; do
    python3 - "$N" "$layout" >"$DIR/in.ngc" <<'PY'
import random, sys
n, layout = int(sys.argv[1]), sys.argv[2]
random.seed(1)
out = ["G21 G90", "G0 Z1", "M3 S1000"]
for i in range(n):
    if layout == "column":
        x, y = 10.0, (i * 7919 % n) * 0.01
    else:
        x, y = random.uniform(0, 300), random.uniform(0, 300)
    out += [f"G0 X{x:.3f} Y{y:.3f}", "G1 Z-0.1 F100", f"G1 X{x + 0.5:.3f} F200", "G0 Z1"]
out += ["M5", "M30"]
print("\n".join(out))
PY
    start=$(date +%s.%N)
    "$BIN" run --emit gcode --pass "order-paths:max_groups=$((N + 1))" "$DIR/in.ngc" -o "$DIR/out.ngc" 2>"$DIR/err" || true
    secs=$(echo "$(date +%s.%N) - $start" | bc)
    echo "$layout: $N groups in $secs s: $(grep -o 'travel .*' "$DIR/err" | head -1)"
    if (( $(echo "$secs > $LIMIT" | bc) )); then
        echo "error: $layout took over $LIMIT s" >&2
        status=1
    fi
done
exit $status
