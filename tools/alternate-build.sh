#!/usr/bin/env bash
# Compares two builds of `vds-bench` on one scene's end-to-end build (`vds-bench one`: read,
# weld, vertex tree, in a fresh process) by running them alternately, so that the VM's drift
# (on the dev VMs the rate at which fresh memory is handed out moves severalfold, see
# `vds-bench first-touch`) hits both alike. Prints, per binary, the median over the rounds of
# the total, each phase and the peak memory.
#
#   cp target/release/vds-bench /tmp/vds-bench-before   # build, copy, change, rebuild, copy
#   tools/alternate-build.sh 5 out/bench/cad-10000000.ply /tmp/vds-bench-before /tmp/vds-bench-after
set -euo pipefail
if [ $# -ne 4 ]; then
    echo "usage: $0 ROUNDS SCENE BINARY_A BINARY_B" >&2
    exit 2
fi
rounds=$1 scene=$2 a=$3 b=$4
runs=$(mktemp)
trap 'rm -f "$runs"' EXIT
for _ in $(seq "$rounds"); do
    echo "A $("$a" one "$scene")" >>"$runs"
    echo "B $("$b" one "$scene")" >>"$runs"
done
python3 - "$runs" "$a" "$b" <<'PY'
import json, statistics, sys
rows = {"A": [], "B": []}
for line in open(sys.argv[1]):
    which, report = line.split(" ", 1)
    rows[which].append(json.loads(report))
phases = ["clustering", "adjacency", "attributes", "subtris"]
for which, binary in (("A", sys.argv[2]), ("B", sys.argv[3])):
    runs = rows[which]
    median = lambda f: statistics.median(f(r) for r in runs)
    parts = [f"total {median(lambda r: r['seconds']):.3f} s",
             f"read + weld {median(lambda r: r['import_seconds']):.3f}"]
    parts += [f"{name} {median(lambda r, k=k: r['phase_seconds'][k]):.3f}"
              for k, name in enumerate(phases)]
    parts.append(f"peak {median(lambda r: r['peak_rss_bytes']) / 1e6:.0f} MB")
    print(f"{binary}: " + ", ".join(parts))
PY
