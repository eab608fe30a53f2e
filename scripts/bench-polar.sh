#!/usr/bin/env bash
# Polar printer pipeline benchmark: the whole polar-printer preset against the identity
# pipeline on the same >= 50 MB 3D-print file, in one run.
#
# Usage (from anywhere):  bash scripts/bench-polar.sh [SIZE_MB]     (default 50)
#
# 1. Generates target/bench-data/polar_<SIZE_MB>MB.gcode (>= SIZE_MB * 10^6 bytes) by
#    plain repetition of a corpus PrusaSlicer file (as scripts/bench-peers.sh does), and
#    target/bench-data/polar-printer-centred.toml: passes/polar-printer.toml with
#    polar-ik's `center` on the part's centre (the slicer's bed origin is a corner).
# 2. Builds the release binary.
# 3. Times whole processes under /usr/bin/time -f '%e %M' (peak RSS KiB; wall time taken
#    at ms resolution around it, as %e has only 10 ms):
#      identity: ncpost run --emit gcode
#      polar:    ncpost run --config <centred preset>   (polar-ik, valve-lookahead,
#                extrude-rate, verify; RepRapFirmware output)
# 4. Prints a markdown table, the throughput ratio polar / identity, and whether the
#    targets hold (peak RSS <= 16 MB, ratio >= 0.15: the floors of BENCHMARKS.md). Exits non-zero if a run fails or
#    writes nothing (not when a target is missed: that is reported).
#
# Environment knobs:
#   BENCH_REPEAT=N      runs per pipeline; best wall time and largest RSS kept (default 1)
#   BENCH_SOURCE=PATH   corpus file to repeat (default: PrusaSlicer MINI cube)
#   BENCH_CENTER="X, Y" the table centre in slicer coordinates (default "90.0, 90.0")
#
# MB means 10^6 bytes throughout. Everything generated lives under target/.
set -euo pipefail
export LC_ALL=C # '.' decimal point in EPOCHREALTIME and awk

cd "$(dirname "$0")/.."
REPO_ROOT=$(pwd)

SIZE_MB=${1:-50}
if ! [[ $SIZE_MB =~ ^[1-9][0-9]*$ ]]; then
    echo "usage: bash scripts/bench-polar.sh [SIZE_MB]   (positive integer, default 50)" >&2
    exit 2
fi
REPEAT=${BENCH_REPEAT:-1}
[[ $REPEAT =~ ^[1-9][0-9]*$ ]] || { echo "BENCH_REPEAT must be a positive integer" >&2; exit 2; }
SOURCE=${BENCH_SOURCE:-../shared/corpus/gcode/gcodenom_mini_cube_a_prusaslicer.gcode}
CENTER=${BENCH_CENTER:-90.0, 90.0}

DATA=target/bench-data
FILE=$DATA/polar_${SIZE_MB}MB.gcode
PRESET=$DATA/polar-printer-centred.toml
mkdir -p "$DATA"

log() { echo "[bench-polar] $*" >&2; }
# shellcheck source=scripts/bench-lib.sh
source "$REPO_ROOT/scripts/bench-lib.sh"

if [[ ! -x /usr/bin/time ]]; then
    echo "error: /usr/bin/time is missing; install the Debian package 'time'" >&2
    exit 1
fi
if [[ ! -f $SOURCE ]]; then
    echo "error: corpus file $SOURCE not found (expected ../shared/corpus next to the repo)" >&2
    exit 1
fi

# ---------------------------------------------------------------- data -----
repeat_to $((SIZE_MB * 1000000)) "$FILE" "$SOURCE"

grep -q '^center = \[0.0, 0.0\]$' passes/polar-printer.toml || {
    echo "error: passes/polar-printer.toml has no 'center = [0.0, 0.0]' line to replace" >&2
    exit 1
}
sed "s/^center = \[0.0, 0.0\]$/center = [$CENTER]/" passes/polar-printer.toml >"$PRESET"

# ---------------------------------------------------------------- build ----
BIN=${CARGO_TARGET_DIR:-target}/release
log "building the release binary"
cargo build --release --bin ncpost

# ---------------------------------------------------------------- runs -----
declare -a ROWS=() FAILED=()
declare -A WALL=() MBPS=() RSS=() CMD=() OUTB=()

# timed NAME OUT CMD...: best_of on $FILE; CMD writes OUT.
timed() {
    local name=$1 out=$2
    shift 2
    CMD[$name]="$*"
    ROWS+=("$name")
    best_of "$name" "$FILE" "$out" "$@"
    [[ ${WALL[$name]} == FAILED ]] || OUTB[$name]=$(fsize "$out")
}

ID_OUT=$DATA/polar-identity.out.gcode
POLAR_OUT=$DATA/polar-preset.out.gcode
timed identity "$ID_OUT" "$BIN/ncpost" run -q --emit gcode -o "$ID_OUT" "$FILE"
timed polar-printer "$POLAR_OUT" "$BIN/ncpost" run -q --config "$PRESET" -o "$POLAR_OUT" "$FILE"

# ---------------------------------------------------------------- report ---
ratio() {
    awk -v a="${1:-}" -v b="${2:-}" 'BEGIN {
        if (a ~ /^[0-9.]+$/ && b ~ /^[0-9.]+$/ && b + 0 > 0) printf "%.3f", a / b; else print "n/a" }'
}
R=$(ratio "${MBPS[polar-printer]:-}" "${MBPS[identity]:-}")

echo
echo "## Polar printer pipeline ($(date -u +%Y-%m-%dT%H:%MZ), $(nproc) cores, best of $REPEAT)"
echo
echo "Invocation: \`bash scripts/bench-polar.sh $SIZE_MB\` (BENCH_REPEAT=$REPEAT, centre $CENTER)"
echo "Input: \`$FILE\` ($(fsize "$FILE") bytes) = \`$SOURCE\` repeated; MB = 10^6 bytes."
echo
echo "| pipeline | input MB | output MB | wall s | input MB/s | peak RSS MB |"
echo "| --- | ---: | ---: | ---: | ---: | ---: |"
for name in "${ROWS[@]}"; do
    o=$(awk -v b="${OUTB[$name]:-0}" 'BEGIN { printf "%.1f", b / 1e6 }')
    i=$(awk -v b="$(fsize "$FILE")" 'BEGIN { printf "%.1f", b / 1e6 }')
    echo "| $name | $i | $o | ${WALL[$name]} | ${MBPS[$name]:-} | ${RSS[$name]:-} |"
done
echo
echo "- throughput polar-printer / identity: **$R** (floor >= 0.15)"
ok_rss=$(awk -v r="${RSS[polar-printer]:-999999}" 'BEGIN { print (r <= 16) ? "yes" : "NO" }')
ok_ratio=$(awk -v r="$R" 'BEGIN { print (r ~ /^[0-9.]+$/ && r >= 0.15) ? "yes" : "NO" }')
echo "- polar-printer peak RSS <= 16 MB: **$ok_rss**; throughput ratio >= 0.15: **$ok_ratio**"
if [[ -s $POLAR_OUT ]]; then
    echo "- polar output: $(grep -c '^M42 P0 S1' "$POLAR_OUT") valve opens, $(grep -c '^G4 ' "$POLAR_OUT") dwells"
fi
echo
echo "Commands (run from \`$REPO_ROOT\`, each under \`/usr/bin/time -f '%e %M'\`):"
echo
for name in "${ROWS[@]}"; do
    echo "- $name: \`${CMD[$name]}\`"
done

if ((${#FAILED[@]})); then
    echo
    echo "FAILED runs: ${FAILED[*]}" >&2
    exit 1
fi
