#!/usr/bin/env bash
# Fuzz smoke run: runs the `pipeline` cargo-fuzz target for N seconds (default 30)
# starting from the committed seeds in fuzz/seeds, and fails if it finds a crash.
#
#   scripts/fuzz-smoke.sh [SECONDS]
#
# Works with the stable toolchain: libFuzzer's coverage instrumentation needs only
# stable rustc flags; what needs nightly is a sanitizer, so this runs with
# `--sanitizer none` (Rust code is memory-safe; the target looks for panics).
# Installs cargo-fuzz when it is missing. The first run builds the instrumented target
# (a few minutes); later runs reuse fuzz/target.
#
# A crash is saved under fuzz/artifacts/pipeline/ and printed (hex) in the log;
# minimise it with
#   cargo fuzz tmin --sanitizer none pipeline fuzz/artifacts/pipeline/crash-...
set -euo pipefail

seconds="${1:-30}"
case "$seconds" in
  '' | *[!0-9]*) echo "usage: $0 [SECONDS]" >&2; exit 2 ;;
esac

root="$(cd "$(dirname "${BASH_SOURCE[0]}")/.." && pwd)"
cd "$root"

if ! cargo fuzz --version >/dev/null 2>&1; then
  echo "fuzz-smoke: installing cargo-fuzz" >&2
  cargo install cargo-fuzz --locked
fi
# libfuzzer-sys compiles libFuzzer (C++).
if ! command -v c++ >/dev/null 2>&1; then
  if [ "$(id -u)" = 0 ] && command -v apt-get >/dev/null 2>&1; then
    echo "fuzz-smoke: installing a C++ compiler" >&2
    apt-get update -qq && DEBIAN_FRONTEND=noninteractive apt-get install -y -qq g++ >/dev/null
  else
    echo "fuzz-smoke: a C++ compiler (c++) is needed to build libFuzzer" >&2
    exit 2
  fi
fi

# A fresh working corpus each run: the seeds are read, never written.
corpus="$(mktemp -d)"
trap 'rm -rf "$corpus"' EXIT
artifacts="$root/fuzz/artifacts/pipeline"
mkdir -p "$artifacts"
before="$(ls "$artifacts" | wc -l)"

echo "fuzz-smoke: building the fuzz target" >&2
cargo fuzz build --sanitizer none pipeline

echo "fuzz-smoke: fuzzing for ${seconds}s from fuzz/seeds" >&2
status=0
cargo fuzz run --sanitizer none pipeline "$corpus" "$root/fuzz/seeds" -- \
  -max_total_time="$seconds" -max_len=4096 -timeout=10 -rss_limit_mb=2048 \
  -print_final_stats=1 -artifact_prefix="$artifacts/" || status=$?

after="$(ls "$artifacts" | wc -l)"
if [ "$status" -ne 0 ] || [ "$after" -ne "$before" ]; then
  echo "fuzz-smoke: FAILED (exit $status); new artifacts in fuzz/artifacts/pipeline:" >&2
  for f in $(ls -t "$artifacts" | head -n 3); do
    echo "--- $f" >&2
    od -A d -c "$artifacts/$f" | head -n 40 >&2
  done
  exit 1
fi
echo "fuzz-smoke: no crash in ${seconds}s"
