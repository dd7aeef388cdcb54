#!/usr/bin/env bash
# Compares two builds of a criterion benchmark on a noisy machine: runs the BEFORE and AFTER
# bench binaries alternately ROUNDS times (default 4) and prints each benchmark's median
# throughput per build and their ratio. One binary's runs can differ by 20 % on a busy 2-core
# machine; alternating puts both builds under the same drift.
#
#   cargo bench --profile release --bench trace --no-run   # in each tree (own CARGO_TARGET_DIR)
#   scripts/bench/ab.sh BEFORE_BIN AFTER_BIN [ROUNDS] [FILTER]
#
# BIN is the executable cargo names (target/release/deps/trace-<hash>); copy it away before the
# other build overwrites it. FILTER defaults to "trace/lens2|trace/kinds". Used for the kernel's
# `turn` helper (docs/decisions.md, 2026-11-30).
set -euo pipefail
before=$1 after=$2 rounds=${3:-4} filter=${4:-"trace/lens2|trace/kinds"}
log=$(mktemp)
for i in $(seq 1 "$rounds"); do
    for v in before after; do
        bin=$before; [ "$v" = after ] && bin=$after
        "$bin" --bench "$filter" --warm-up-time 1 --measurement-time 3 --noplot 2>/dev/null |
            awk -v v="$v" '/^[a-z]+\//{n=$1} /thrpt:/ && !/%/{print v, n, $4}' >> "$log"
    done
done
python3 - "$log" <<'PY'
import collections, statistics, sys
runs = collections.defaultdict(lambda: collections.defaultdict(list))
for line in open(sys.argv[1]):
    v, name, x = line.split()
    runs[name][v].append(float(x))
print(f"{'benchmark':40s} {'before':>9s} {'after':>9s} {'ratio':>6s}  (medians, Melem/s)")
for name, r in runs.items():
    b, a = statistics.median(r["before"]), statistics.median(r["after"])
    print(f"{name:40s} {b:9.2f} {a:9.2f} {a / b:6.3f}")
PY
rm -f "$log"
