#!/usr/bin/env bash
# CPU-time and instruction-count companion to scripts/bench-peers.sh, for a loaded or
# shared machine, where wall time mostly measures the other processes.
#
# Usage (from anywhere):  bash scripts/bench-cpu.sh [SIZE_MB...]      (default: 100)
#
# For each SIZE_MB it times, BENCH_REPEAT times (default 3), whole processes under
# /usr/bin/time -f '%e %U %S %M' and prints the best wall, best user+sys CPU and the
# largest peak RSS of:
#   - ncpost identity pipeline: $CARGO_TARGET_DIR/release/ncpost run --emit gcode -o OUT FILE
#   - the gcode crate 0.7 parse-only example (skipped with PEERS=0)
#   - wc -l (a floor)
# on target/bench-data/peers_<SIZE_MB>MB.gcode, the same file bench-peers.sh makes (this
# script makes it the same way, by repeating the corpus file, when it is missing).
#
# With CALLGRIND=1 it also counts instructions (valgrind --tool=callgrind, which is
# independent of load) of ncpost and the gcode crate on the first CALLGRIND_MB MB
# (default 5) of whole lines, and prints instructions per input byte. The profiles stay
# in target/bench-data/callgrind.*.out for callgrind_annotate.
#
# It builds nothing unless the binaries are missing: run `cargo build --release --bin
# ncpost --example peer_gcode_crate` first to measure the current tree.
set -euo pipefail
export LC_ALL=C
cd "$(dirname "$0")/.."

REPEAT=${BENCH_REPEAT:-3}
PEERS=${PEERS:-1}
CALLGRIND=${CALLGRIND:-0}
CG_MB=${CALLGRIND_MB:-5}
SOURCE=${BENCH_SOURCE:-../shared/corpus/gcode/gcodenom_mini_cube_a_prusaslicer.gcode}
DATA=target/bench-data
OUT=$DATA/cpu-out.gcode
NCPOST=${CARGO_TARGET_DIR:-target}/release/ncpost
PEER=${CARGO_TARGET_DIR:-target}/release/examples/peer_gcode_crate
mkdir -p "$DATA"
sizes=("$@")
((${#sizes[@]})) || sizes=(100)

log() { echo "[bench-cpu] $*" >&2; }
# shellcheck source=scripts/bench-lib.sh
source "$(pwd)/scripts/bench-lib.sh"

if [[ ! -x $NCPOST || ! -x $PEER ]]; then
    log "building release binaries"
    cargo build --release --bin ncpost --example peer_gcode_crate
fi

# run NAME FILE CMD...: best wall / user+sys over REPEAT runs, max RSS.
run() {
    local name=$1 file=$2
    shift 2
    local bytes best_w="" best_c="" best_u="" best_s="" rss=0 i w u s m c
    bytes=$(fsize "$file")
    cat "$file" >/dev/null
    for ((i = 1; i <= REPEAT; i++)); do
        /usr/bin/time -f '%e %U %S %M' -o "$DATA/cpu.time" "$@" >/dev/null 2>"$DATA/cpu.stderr" || {
            log "FAILED: $name ($*)"; tail -n 5 "$DATA/cpu.stderr" >&2; return 1; }
        read -r w u s m < <(tail -n 1 "$DATA/cpu.time")
        c=$(awk -v u="$u" -v s="$s" 'BEGIN { printf "%.2f", u + s }')
        if [[ -z $best_w ]] || awk -v a="$w" -v b="$best_w" 'BEGIN { exit !(a < b) }'; then best_w=$w; fi
        if [[ -z $best_c ]] || awk -v a="$c" -v b="$best_c" 'BEGIN { exit !(a < b) }'; then best_c=$c; best_u=$u; best_s=$s; fi
        ((m > rss)) && rss=$m
    done
    awk -v n="$name" -v b="$bytes" -v w="$best_w" -v c="$best_c" -v u="$best_u" -v s="$best_s" -v r="$rss" 'BEGIN {
        mw = (w > 0 ? sprintf("%.1f", b / 1e6 / w) : "n/a (< 10 ms)")
        mc = (c > 0 ? sprintf("%.1f", b / 1e6 / c) : "n/a (< 10 ms)")
        printf "| %s | %.1f | %.2f | %.2f (%.2f + %.2f) | %s | %s | %.1f |\n",
            n, b / 1e6, w, c, u, s, mw, mc, r / 1024 }'
}

echo "## CPU time ($(date -u +%Y-%m-%dT%H:%MZ), $(nproc) cores, load $(cut -d' ' -f1-3 /proc/loadavg), best of $REPEAT)"
echo
echo "| tool | file MB | wall s | CPU s (user + sys) | MB/s wall | MB/s CPU | peak RSS MB |"
echo "| --- | ---: | ---: | ---: | ---: | ---: | ---: |"
for size in "${sizes[@]}"; do
    file=$DATA/peers_${size}MB.gcode
    repeat_to $((size * 1000000)) "$file" "$SOURCE"
    run "ncpost ($size MB)" "$file" "$NCPOST" run --emit gcode -o "$OUT" "$file"
    if [[ $PEERS == 1 ]]; then
        run "gcode-crate-0.7 ($size MB)" "$file" "$PEER" "$file"
        run "wc -l ($size MB)" "$file" wc -l "$file"
    fi
done

if [[ $CALLGRIND == 1 ]]; then
    prefix=$DATA/cpu_prefix_${CG_MB}MB.gcode
    if [[ ! -f $prefix ]]; then
        repeat_to $((CG_MB * 1000000 + 1000000)) "$prefix.src" "$SOURCE"
        head -c $((CG_MB * 1000000)) "$prefix.src" | sed '$d' >"$prefix"
        rm -f "$prefix.src"
    fi
    bytes=$(fsize "$prefix")
    echo
    echo "Instructions (callgrind, user space only) on \`$prefix\` ($bytes bytes):"
    echo
    echo "| tool | instructions | per input byte |"
    echo "| --- | ---: | ---: |"
    for tool in ncpost gcode-crate-0.7; do
        cg=$DATA/callgrind.$tool.out
        if [[ $tool == ncpost ]]; then cmd=("$NCPOST" run --emit gcode -o "$OUT" "$prefix"); else cmd=("$PEER" "$prefix"); fi
        valgrind --tool=callgrind --callgrind-out-file="$cg" "${cmd[@]}" >/dev/null 2>"$DATA/cpu.cg.stderr"
        ir=$(grep -m1 '^summary:' "$cg" | awk '{ print $2 }')
        awk -v t="$tool" -v i="$ir" -v b="$bytes" 'BEGIN { printf "| %s | %d | %.0f |\n", t, i, i / b }'
    done
fi
