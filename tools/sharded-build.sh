#!/usr/bin/env bash
# The sharded build of one scene against the in-memory build, in one sitting: wall time and
# peak memory (`/usr/bin/time`'s maximum resident set) of the in-memory build, of `plan`, of
# each shard, and of the merge; the shards run once one at a time and once as PROCS parallel
# processes (`xargs -P`). Checks that both builds wrote the same bytes.
#
#   tools/sharded-build.sh out/bench/cad-10000000.ply 4 2
set -euo pipefail
if [ $# -ne 3 ]; then
    echo "usage: $0 SCENE SHARDS PROCS" >&2
    exit 2
fi
scene=$1 shards=$2 procs=$3
bin=${VDS_BUILD:-target/release/vds-build}
work=$(mktemp -d)
trap 'rm -rf "$work"' EXIT
measure() { # LABEL COMMAND...: prints "LABEL seconds peak-MB"
    local label=$1
    shift
    /usr/bin/time -f "$label %e %M" "$@" 2>&1 >/dev/null | tail -1 |
        awk '{printf "%-22s %7.2f s %7.0f MB\n", $1, $2, $3 / 1024}'
}
measure in-memory "$bin" "$scene" -o "$work/in-memory.vdt" -q
measure plan "$bin" plan "$scene" --shards "$shards" -o "$work/plan.json" -q
start=$(date +%s.%N)
for k in $(seq 0 $((shards - 1))); do
    measure "shard-$k" "$bin" shard "$work/plan.json" --index "$k" -o "$work/shard-$k.vdtpart" -q
done
end=$(date +%s.%N)
echo "shards one at a time   $(echo "$end - $start" | bc) s"
start=$(date +%s.%N)
seq 0 $((shards - 1)) | xargs -P "$procs" -I{} "$bin" shard "$work/plan.json" --index {} \
    -o "$work/shard-{}.vdtpart" -q --threads $((($(nproc) + procs - 1) / procs))
end=$(date +%s.%N)
echo "shards, $procs processes    $(echo "$end - $start" | bc) s"
measure merge "$bin" merge "$work/plan.json" "$work"/shard-*.vdtpart -o "$work/sharded.vdt" -q
cmp "$work/in-memory.vdt" "$work/sharded.vdt" && echo "same bytes: yes"
du -b "$work"/plan.shard-*.vdtin | awk '{s+=$1} END {printf "shard inputs %.1f MB\n", s / 1e6}'
du -b "$work"/shard-*.vdtpart | awk '{s+=$1} END {printf "parts        %.1f MB\n", s / 1e6}'
