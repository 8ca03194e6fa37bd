#!/usr/bin/env bash
# Compares two builds of `vds-bench` on the runtime benchmark by running them alternately,
# so that a VM's drift (which on the dev VMs moves single runs by 20-30 %) hits both alike.
# Prints, per binary and threshold, the median over the rounds of each run's median and p99
# adjust time.
#
#   cp target/release/vds-bench /tmp/vds-bench-before   # build, copy, change, rebuild, copy
#   tools/alternate-cut.sh 9 /tmp/vds-bench-before /tmp/vds-bench-after
#
# Extra arguments after the two binaries replace the default `cut` arguments.
set -euo pipefail
if [ $# -lt 3 ]; then
    echo "usage: $0 ROUNDS BINARY_A BINARY_B [vds-bench arguments...]" >&2
    exit 2
fi
rounds=$1 a=$2 b=$3
shift 3
args=("$@")
if [ ${#args[@]} -eq 0 ]; then
    args=(cut --frames 600 --no-fidelity --resident-only --no-bunny)
fi
for _ in $(seq "$rounds"); do
    for binary in "$a" "$b"; do
        # Lines look like "  t=1 px   Incidence resident adjust median  2.012 ms  p99  6.759 ms ..."
        "$binary" "${args[@]}" | awk -v who="$binary" '/adjust median/ {
            m = ""; p = ""
            for (i = 1; i <= NF; i++) {
                if ($i == "median" && m == "") m = $(i + 1)
                if ($i == "p99" && p == "") p = $(i + 1)
            }
            print who, $1, $3, $4, m, p
        }'
    done
done | sort -k1,4 -s | awk '
    function median(list, n,   sorted, i, j, t) {
        for (i = 1; i <= n; i++) sorted[i] = list[i]
        for (i = 2; i <= n; i++) for (j = i; j > 1 && sorted[j - 1] > sorted[j]; j--) {
            t = sorted[j]; sorted[j] = sorted[j - 1]; sorted[j - 1] = t
        }
        return n % 2 ? sorted[(n + 1) / 2] : (sorted[n / 2] + sorted[n / 2 + 1]) / 2
    }
    function flush() {
        if (key != "") printf "%s: median %.3f ms, p99 %.3f ms over %d runs\n", key, median(ms, n), median(p99, n), n
    }
    {
        k = $1 " " $2 " " $3 " " $4
        if (k != key) { flush(); key = k; n = 0 }
        n++; ms[n] = $5; p99[n] = $6
    }
    END { flush() }'
