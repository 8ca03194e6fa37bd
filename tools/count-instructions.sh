#!/usr/bin/env bash
# Counts the instructions a `vds-bench` binary executes for three fixed jobs, under valgrind's
# cachegrind (no cache simulation): building the generated 1 M-triangle scene (`vds-bench one`),
# decoding every page of its `.vdt` file (`vds-bench decode`, one digest pass and one timed
# pass), and the runtime flying through that file for 200 frames at 1 and 5 px with every page
# decoded first (`vds-bench cut --vdt`). Instruction counts do not drift with the machine as
# timings do (the dev VMs move single runs by 20-30 %), so they show whether a change did less
# work; memory-bound code (the runtime) can still get slower or faster at equal counts, so
# confirm with alternating timed runs afterwards. Needs valgrind; run from the repository root
# after `cargo build --release -p vds-bench -p vds-gen -p vds-build`.
#
#   tools/count-instructions.sh target/release/vds-bench
#
# The 1 M scene and file are made in out/ on first use (`vds-gen`, `vds-build`).
set -euo pipefail
if [ $# -ne 1 ]; then
    echo "usage: $0 VDS_BENCH_BINARY" >&2
    exit 2
fi
binary=$1
command -v valgrind >/dev/null || { echo "valgrind is not installed" >&2; exit 1; }
scene=out/bench/cad-1000000.ply
file=out/cad-1M.vdt
mkdir -p out/bench
[ -f "$scene" ] || target/release/vds-gen --triangles 1M --out "$scene"
[ -f "$file" ] || target/release/vds-build "$scene" -o "$file" --quiet
count() {
    local what=$1
    shift
    local log
    log=$(mktemp)
    valgrind --tool=cachegrind --cache-sim=no --cachegrind-out-file=/dev/null "$@" \
        >/dev/null 2>"$log"
    # The summary line reads "==PID== I   refs:      1,103,141,719".
    printf '%-52s %s instructions\n' "$what" "$(awk '/I +refs:/ {print $NF}' "$log")"
    rm -f "$log"
}
count "build of $scene (vds-bench one)" "$binary" one "$scene"
count "decode of $file, two passes" "$binary" --runs 1 decode "$file"
count "runtime on $file, 2 x 200 frames" "$binary" cut --vdt "$file" --frames 200 \
    --no-fidelity --resident-only
