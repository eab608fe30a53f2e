#!/usr/bin/env bash
# Whole-process benchmark of the E-moc X5 pipeline against the seed's Python post.
#
# Usage (from anywhere):  bash scripts/bench-5axis.sh [N]     (default 1000000 GOTO points)
#
# 1. Generates target/bench-data/five_axis_<N>.cl with scripts/gen-cl.py (a tool axis that
#    varies on every point).
# 2. Builds the release binary.
# 3. Times whole processes under /usr/bin/time -f '%e %M' (wall seconds at ms resolution
#    around it, peak RSS KiB):
#      ncpost run --preset emoc-x5 (parse, ik, unwrap-rotary, densify, feed, limits,
#      verify, RepRapFirmware output), and scripts/seed_post.py (the seed formulas, IK
#      only, pure Python) on the same file. Both write their G-code to a file in
#      target/bench-data (ncpost with -o, which replaces the file atomically after an
#      fdatasync; the Python post through its standard output), each over its output of
#      the run before, as a user re-running a post does.
# 4. Prints a markdown table and the speed ratio; exits non-zero if a run fails.
#
# BENCH_REPEAT=N runs each tool N times and keeps the best wall time (default 1).
set -euo pipefail
export LC_ALL=C

cd "$(dirname "$0")/.."
N=${1:-1000000}
REPEAT=${BENCH_REPEAT:-1}
DATA=target/bench-data
mkdir -p "$DATA"
CL="$DATA/five_axis_${N}.cl"
if [[ ! -s "$CL" ]]; then
  python3 scripts/gen-cl.py "$N" > "$CL.tmp" && mv "$CL.tmp" "$CL"
fi
cargo build --release --quiet

measure() { # name, output file, command...
  local name=$1 out=$2; shift 2
  local best="" rss=0
  for _ in $(seq "$REPEAT"); do
    local t0=$EPOCHREALTIME
    /usr/bin/time -f '%M' -o "$DATA/time.txt" "$@" > "$out"
    local t1=$EPOCHREALTIME
    local wall
    wall=$(awk -v a="$t0" -v b="$t1" 'BEGIN { printf "%.3f", b - a }')
    local r
    r=$(tail -1 "$DATA/time.txt")
    (( r > rss )) && rss=$r
    if [[ -z "$best" ]] || awk -v a="$wall" -v b="$best" 'BEGIN { exit !(a < b) }'; then
      best=$wall
    fi
  done
  printf '| %s | %s | %.1f |\n' "$name" "$best" "$(awk -v k="$rss" 'BEGIN { print k / 1024 }')"
  echo "$best" > "$DATA/$name.wall"
}

SIZE=$(stat -c %s "$CL")
echo "input: $CL ($N GOTO points, $SIZE bytes)"
echo
echo "| program | wall s | peak RSS MB |"
echo "|---|---|---|"
measure ncpost /dev/null "${CARGO_TARGET_DIR:-target}/release/ncpost" run --quiet --preset emoc-x5 "$CL" -o "$DATA/five_axis_${N}.gcode"
measure seed_post "$DATA/seed_post_${N}.gcode" python3 scripts/seed_post.py "$CL"
echo
awk -v a="$(cat "$DATA/seed_post.wall")" -v b="$(cat "$DATA/ncpost.wall")" \
  'BEGIN { printf "ncpost is %.1fx faster than the seed post in Python\n", a / b }'
lines=$(wc -l < "$DATA/five_axis_${N}.gcode")
echo "ncpost wrote $lines lines"
