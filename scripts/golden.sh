#!/usr/bin/env bash
# Output guard: compiles every file of ../shared/corpus (and generated 5-axis and polar
# programs) under every preset it runs under, with a baseline binary built from BASE_REV
# and with the working tree's binary, and compares standard output, standard error and the
# exit code byte for byte.
#
# Usage (from anywhere):  bash scripts/golden.sh [BASE_REV]      (default 7138545)
#
# The baseline is built once per revision in target/golden/<rev>/ (a git worktree and its
# own target directory); every run's outputs go to target/golden/{base,new}/. The release
# profile is built without LTO for both binaries: Rust does not contract or reorder
# floating-point arithmetic, so the printed numbers do not depend on the optimiser.
#
# GOLDEN_BASE_BIN=PATH uses an already built baseline binary instead.
#
# Exit status: 0 when every case is identical, 1 when one differs (the differing cases are
# listed with the first lines of their diff), 2 on a usage or build error.
set -euo pipefail
export LC_ALL=C
cd "$(dirname "$0")/.."
ROOT=$(pwd)
BASE_REV=${1:-7138545}
CORPUS=$ROOT/../shared/corpus
[ -d "$CORPUS/gcode" ] || { echo "error: $CORPUS is missing" >&2; exit 2; }
export CARGO_PROFILE_RELEASE_LTO=false CARGO_PROFILE_RELEASE_CODEGEN_UNITS=16

GOLD=$ROOT/target/golden
BASE_SRC=$GOLD/$BASE_REV/src
BASE_BIN=${GOLDEN_BASE_BIN:-$GOLD/$BASE_REV/ncpost}
mkdir -p "$GOLD"
if [ ! -x "$BASE_BIN" ]; then
    rm -rf "$BASE_SRC"
    git worktree prune
    git worktree add --detach "$BASE_SRC" "$BASE_REV" >/dev/null
    (cd "$BASE_SRC" && CARGO_TARGET_DIR=$GOLD/$BASE_REV/target cargo build --release --quiet)
    cp "$GOLD/$BASE_REV/target/release/ncpost" "$BASE_BIN"
    git worktree remove --force "$BASE_SRC"
fi
cargo build --release --quiet
NEW_BIN=$ROOT/target/release/ncpost

# Generated inputs: 20k 5-axis GOTO points, and a polar preset centred on the MINI's bed.
DATA=$GOLD/data
mkdir -p "$DATA"
[ -s "$DATA/emoc_20k.cl" ] || python3 scripts/gen-cl.py 20000 >"$DATA/emoc_20k.cl"
sed 's/^center = .*/center = [90.0, 90.0]/' passes/polar-printer.toml >"$DATA/polar-centred.toml"
grep -q '^center = \[90.0, 90.0\]' "$DATA/polar-centred.toml" || {
    echo "error: passes/polar-printer.toml has no 'center = ' line to centre" >&2
    exit 2
}

# One case per line: a name, then the arguments after `ncpost run`.
cases() {
    local f b m
    for f in "$CORPUS"/gcode/*; do
        b=$(basename "$f")
        echo "gcode-identity-$b|--emit gcode $f"
        echo "gcode-ir-$b|--emit ir $f"
        echo "gcode-duet-cnc-$b|--preset duet-cnc $f"
        echo "gcode-grbl-$b|--emit grbl $f"
        echo "gcode-polar-$b|--preset polar-printer $f"
        echo "gcode-polar-centred-$b|--config $DATA/polar-centred.toml $f"
        echo "gcode-pcb-mill-$b|--preset pcb-mill $f"
        echo "gcode-linearize-$b|--emit gcode --pass linearize-arcs $f"
        echo "gcode-expand-$b|--emit gcode --pass expand-subprograms $f"
        for m in "$CORPUS"/heightmap/*; do
            echo "gcode-heightmap-$(basename "$m")-$b|--emit gcode --pass heightmap:map=$m,outside=clamp $f"
        done
    done
    for f in "$CORPUS"/cl/* "$DATA/emoc_20k.cl"; do
        b=$(basename "$f")
        echo "cl-identity-$b|--emit gcode $f"
        for p in emoc-x5 head-head-ab head-table trunnion-bc; do
            echo "cl-$p-$b|--preset $p $f"
        done
    done
    for f in "$CORPUS"/hpgl/*; do
        b=$(basename "$f")
        echo "hpgl-pcb-mill-$b|--preset pcb-mill --from hpgl $f"
        echo "hpgl-pcb-order-$b|--preset pcb-mill --from hpgl --pass order-paths $f"
        echo "hpgl-pcb-mirror-$b|--preset pcb-mill --from hpgl --pass mirror $f"
        echo "hpgl-pcb-both-$b|--preset pcb-mill --from hpgl --pass mirror --pass order-paths $f"
        echo "hpgl-grbl-$b|--preset pcb-mill --from hpgl --emit grbl $f"
        for m in "$CORPUS"/heightmap/*; do
            echo "hpgl-heightmap-$(basename "$m")-$b|--preset pcb-mill --from hpgl --pass heightmap:map=$m,outside=clamp $f"
        done
    done
}

run_all() {
    local bin=$1 dir=$2 name args
    rm -rf "$dir"
    mkdir -p "$dir"
    while IFS='|' read -r name args; do
        # shellcheck disable=SC2086
        (cd "$DATA" && "$bin" run $args >"$dir/$name.out" 2>"$dir/$name.err"; echo $? >"$dir/$name.rc") || true
        # Paths differ between the two runs only where the diagnostics name the input.
    done < <(cases)
}

run_all "$BASE_BIN" "$GOLD/base"
run_all "$NEW_BIN" "$GOLD/new"

total=$(cases | wc -l)
differ=0
while IFS='|' read -r name _; do
    for ext in out err rc; do
        if ! cmp -s "$GOLD/base/$name.$ext" "$GOLD/new/$name.$ext"; then
            differ=$((differ + 1))
            echo "DIFFERS: $name.$ext"
            diff "$GOLD/base/$name.$ext" "$GOLD/new/$name.$ext" | head -8 || true
        fi
    done
done < <(cases)
echo "$total cases, $differ differing outputs (base $BASE_REV, new: working tree)"
[ "$differ" -eq 0 ]
