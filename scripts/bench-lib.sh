# Shared by the bench scripts (sourced, not run). Needs DATA, REPEAT and a `log` function.

fsize() { stat -c %s "$1"; }

# repeat_to MIN_BYTES DEST SOURCE: DEST = SOURCE repeated until it has at least MIN_BYTES
# (an existing DEST that big is kept). The unit is SOURCE ending with a newline, so
# repetitions never glue two lines together.
repeat_to() {
    local min=$1 dest=$2 source=$3
    if [[ -f $dest ]] && (($(fsize "$dest") >= min)); then
        log "reusing $dest ($(fsize "$dest") bytes)"
        return
    fi
    local unit=$DATA/.unit.gcode bytes n i
    cat "$source" >"$unit"
    [[ -z $(tail -c 1 "$unit") ]] || echo >>"$unit"
    bytes=$(fsize "$unit")
    n=$(((min + bytes - 1) / bytes))
    log "generating $dest: $n x $source"
    for ((i = 0; i < n; i++)); do cat "$unit"; done >"$dest.tmp"
    mv "$dest.tmp" "$dest"
}

#
# best_of NAME INPUT OUT CMD...: runs CMD REPEAT times under /usr/bin/time, with INPUT in
# the page cache first. OUT, unless empty, is removed before each run and must exist and
# be non-empty after it. Sets WALL[NAME] to the best wall time in seconds (taken with
# EPOCHREALTIME around /usr/bin/time, since its %e has 10 ms resolution; adds ~1 ms of
# its fork/exec), RSS[NAME] to the largest peak RSS in MB and MBPS[NAME] to INPUT's MB
# per second at the best time; on a failed run WALL[NAME]=FAILED and NAME is appended to
# FAILED. CMD's output is in $DATA/NAME.stdout and .stderr.
best_of() {
    local name=$1 input=$2 out=$3
    shift 3
    local bytes best="" maxrss=0 i t m
    bytes=$(stat -c %s "$input")
    cat "$input" >/dev/null
    for ((i = 1; i <= REPEAT; i++)); do
        log "run $i/$REPEAT: $name: $*"
        [[ -n $out ]] && rm -f "$out"
        local t0=$EPOCHREALTIME t1 why=""
        if ! /usr/bin/time -f '%e %M' -o "$DATA/$name.time" "$@" \
            >"$DATA/$name.stdout" 2>"$DATA/$name.stderr"; then
            why="exit status non-zero"
        elif [[ -n $out && ! -s $out ]]; then
            why="exit 0 but wrote no $out"
        fi
        t1=$EPOCHREALTIME
        if [[ -n $why ]]; then
            log "FAILED: $name: $why (stderr tail below, full in $DATA/$name.stderr)"
            tail -n 20 "$DATA/$name.stderr" >&2 || true
            FAILED+=("$name")
            WALL[$name]=FAILED
            return 0
        fi
        # %M (peak RSS, KiB) is the last line of the -o file.
        read -r _ m < <(tail -n 1 "$DATA/$name.time")
        t=$(awk -v a="$t0" -v b="$t1" 'BEGIN { printf "%.3f", b - a }')
        if [[ -z $best ]] || awk -v a="$t" -v b="$best" 'BEGIN { exit !(a < b) }'; then best=$t; fi
        ((m > maxrss)) && maxrss=$m
    done
    WALL[$name]=$best
    RSS[$name]=$(awk -v k="$maxrss" 'BEGIN { printf "%.1f", k / 1024 }')
    MBPS[$name]=$(awk -v b="$bytes" -v s="$best" 'BEGIN { if (s > 0) printf "%.2f", b / 1e6 / s; else print "n/a" }')
}
