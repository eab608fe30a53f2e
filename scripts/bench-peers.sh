#!/usr/bin/env bash
# Whole-process peer comparison benchmark for ncpost.
#
# Usage (from anywhere):  bash scripts/bench-peers.sh [SIZE_MB]     (default 100)
#
# 1. Generates target/bench-data/peers_<SIZE_MB>MB.gcode (>= SIZE_MB * 10^6
#    bytes) by plain repetition of a corpus PrusaSlicer file, plus a
#    <PYGCODE_PREFIX_MB>-MB prefix of whole lines of it for pygcode.
# 2. Builds release binaries (ncpost and examples/peer_gcode_crate).
# 3. Times whole processes under /usr/bin/time -f '%e %M' (peak RSS KiB; wall
#    time taken at ms resolution around it, as %e has only 10 ms):
#      ncpost identity pipeline, gcode crate 0.7 parse-only, pygcode parse-only
#      (on the prefix file: it is slow), and `wc -l` as a floor.
# 4. Prints a markdown table and the ratios. Exits non-zero if any run fails
#    (for ncpost: also if it exits 0 without writing its -o file). ncpost is
#    skipped, with a message, only while target/release/ncpost does not exist.
#
# Environment knobs:
#   BENCH_REPEAT=N        runs per tool; best wall time and largest RSS kept (default 1)
#   PYGCODE_PREFIX_MB=N   size of pygcode's prefix file in MB (default 5)
#   BENCH_SOURCE=PATH     corpus file to repeat (default: PrusaSlicer mini cube)
#
# MB means 10^6 bytes throughout. Everything generated lives under target/.
set -euo pipefail
export LC_ALL=C # '.' decimal point in EPOCHREALTIME and awk

cd "$(dirname "$0")/.."
REPO_ROOT=$(pwd)

SIZE_MB=${1:-100}
if ! [[ $SIZE_MB =~ ^[1-9][0-9]*$ ]]; then
    echo "usage: bash scripts/bench-peers.sh [SIZE_MB]   (positive integer, default 100)" >&2
    exit 2
fi
REPEAT=${BENCH_REPEAT:-1}
PREFIX_MB=${PYGCODE_PREFIX_MB:-5}
for v in "$REPEAT" "$PREFIX_MB"; do
    [[ $v =~ ^[1-9][0-9]*$ ]] || { echo "BENCH_REPEAT / PYGCODE_PREFIX_MB must be positive integers" >&2; exit 2; }
done
SOURCE=${BENCH_SOURCE:-../shared/corpus/gcode/gcodenom_mini_cube_a_prusaslicer.gcode}

DATA=target/bench-data
VENV=target/bench-venv
FILE=$DATA/peers_${SIZE_MB}MB.gcode
PREFIX=$DATA/peers_prefix_${PREFIX_MB}MB.gcode
OUT=$DATA/out.gcode
mkdir -p "$DATA"

log() { echo "[bench-peers] $*" >&2; }
# shellcheck source=scripts/bench-lib.sh
source "$REPO_ROOT/scripts/bench-lib.sh"

# ---------------------------------------------------------------- tools ----
if [[ ! -x /usr/bin/time ]]; then
    log "/usr/bin/time missing: installing Debian package 'time'"
    if [[ $(id -u) -ne 0 ]]; then
        echo "error: /usr/bin/time is missing and we are not root; run: apt-get install time" >&2
        exit 1
    fi
    apt-get update -qq
    DEBIAN_FRONTEND=noninteractive apt-get install -y -qq time >/dev/null
fi

# ---------------------------------------------------------------- data -----
if [[ ! -f $SOURCE ]]; then
    echo "error: corpus file $SOURCE not found (expected ../shared/corpus next to the repo)" >&2
    exit 1
fi
repeat_to $((SIZE_MB * 1000000)) "$FILE" "$SOURCE"

# pygcode prefix: the first PREFIX_MB MB of the big file, cut back to whole lines.
if [[ ! -f $PREFIX ]]; then
    log "generating $PREFIX (first ${PREFIX_MB} MB of whole lines)"
    repeat_to $((PREFIX_MB * 1000000)) "$PREFIX.src" "$SOURCE"
    head -c $((PREFIX_MB * 1000000)) "$PREFIX.src" | sed '$d' >"$PREFIX.tmp"
    rm -f "$PREFIX.src"
    mv "$PREFIX.tmp" "$PREFIX"
fi

# ---------------------------------------------------------------- build ----
# Binaries are where cargo puts them (CARGO_TARGET_DIR, default target/).
BIN=${CARGO_TARGET_DIR:-target}/release
log "building release binaries"
has_ncpost_bin=$(cargo metadata --no-deps --format-version 1 2>/dev/null | python3 -c '
import json, sys
m = json.load(sys.stdin)
print(any(t["name"] == "ncpost" and "bin" in t["kind"] for p in m["packages"] for t in p["targets"]))
' || echo False)
if [[ $has_ncpost_bin == True ]]; then
    cargo build --release --bin ncpost --example peer_gcode_crate
else
    log "no 'ncpost' bin target declared yet: building the peer example only"
    cargo build --release --example peer_gcode_crate
fi

# ---------------------------------------------------------------- venv -----
PY=$VENV/bin/python
if [[ ! -x $PY ]]; then
    log "creating venv $VENV"
    python3 -m venv "$VENV"
fi
if ! "$PY" -c 'import pygcode' 2>/dev/null; then
    log "installing pygcode into $VENV"
    "$PY" -m pip install -q --disable-pip-version-check 'pygcode==0.2.1'
fi

# ---------------------------------------------------------------- runs -----
declare -a ROWS=() FAILED=()
declare -A WALL=() MBPS=() RSS=() CMD=() SIZE=()

# timed NAME INPUT CMD...: best_of with the table's columns; ncpost must write $OUT.
timed() {
    local name=$1 input=$2
    shift 2
    CMD[$name]="$*"
    SIZE[$name]=$(awk -v b="$(fsize "$input")" 'BEGIN { printf "%.1f", b / 1e6 }')
    ROWS+=("$name")
    local out=""
    [[ $name == ncpost ]] && out=$OUT
    best_of "$name" "$input" "$out" "$@"
    [[ ${WALL[$name]} == FAILED ]] || log "  -> $(head -c 300 "$DATA/$name.stdout" | head -n 1)"
}

if [[ -x $BIN/ncpost ]]; then
    timed ncpost "$FILE" "$BIN/ncpost" run --emit gcode -o "$OUT" "$FILE"
else
    log "SKIP ncpost: $BIN/ncpost does not exist (CLI not built yet)"
fi
timed gcode-crate-0.7 "$FILE" "$BIN/examples/peer_gcode_crate" "$FILE"
timed pygcode-0.2.1 "$PREFIX" "$PY" scripts/peer_pygcode.py "$PREFIX"
timed wc-l "$FILE" wc -l "$FILE"

# ---------------------------------------------------------------- report ---
ratio() { # ratio A B -> A/B with 2 decimals, or n/a
    awk -v a="${1:-}" -v b="${2:-}" 'BEGIN {
        if (a ~ /^[0-9.]+$/ && b ~ /^[0-9.]+$/ && b + 0 > 0) printf "%.2f", a / b; else print "n/a" }'
}

echo
echo "## ncpost peer benchmark ($(date -u +%Y-%m-%dT%H:%MZ), $(nproc) cores, best of $REPEAT)"
echo
echo "Invocation: \`bash scripts/bench-peers.sh $SIZE_MB\` (BENCH_REPEAT=$REPEAT PYGCODE_PREFIX_MB=$PREFIX_MB)"
echo "Input: \`$FILE\` ($(fsize "$FILE") bytes) = \`$SOURCE\` repeated; MB = 10^6 bytes."
echo "**pygcode ran on the ${PREFIX_MB} MB prefix \`$PREFIX\` ($(fsize "$PREFIX") bytes), not the full file: compare its MB/s, not its seconds.**"
echo
echo "| tool | file MB | wall s | MB/s | peak RSS MB |"
echo "| --- | ---: | ---: | ---: | ---: |"
for name in "${ROWS[@]}"; do
    label=$name
    [[ $name == pygcode-0.2.1 ]] && label="$name (prefix file)"
    echo "| $label | ${SIZE[$name]} | ${WALL[$name]} | ${MBPS[$name]:-} | ${RSS[$name]:-} |"
done
echo
if [[ -n ${WALL[ncpost]:-} ]]; then
    echo "- gcode-crate time / ncpost time: **$(ratio "${WALL[gcode-crate-0.7]:-}" "${WALL[ncpost]}")** (> 1: ncpost faster)"
    echo "- ncpost MB/s / pygcode MB/s: **$(ratio "${MBPS[ncpost]:-}" "${MBPS[pygcode-0.2.1]:-}")**"
else
    echo "- gcode-crate time / ncpost time: n/a (ncpost not run)"
    echo "- ncpost MB/s / pygcode MB/s: n/a (ncpost not run)"
fi
echo "- gcode-crate MB/s / pygcode MB/s: $(ratio "${MBPS[gcode-crate-0.7]:-}" "${MBPS[pygcode-0.2.1]:-}")"
echo
echo "Commands (run from \`$REPO_ROOT\`, each under \`/usr/bin/time -f '%e %M'\` for peak RSS; wall s from bash's EPOCHREALTIME around it, since %e has 10 ms resolution):"
echo
for name in "${ROWS[@]}"; do
    echo "- $name: \`${CMD[$name]}\`"
done

if ((${#FAILED[@]})); then
    echo
    echo "FAILED runs: ${FAILED[*]}" >&2
    exit 1
fi
