#!/usr/bin/env bash
# Runs every case of validation/cases.json with `tolray validate --embree` and writes one JSON
# report per case to validation/results/ (not committed). Exits non-zero if any case fails.
# Usage: validation/run.sh [extra tolray validate options, e.g. --trials 10]
set -euo pipefail
cd "$(dirname "$0")/.."
cargo build --release --features embree --bin tolray
bin="${CARGO_TARGET_DIR:-target}/release/tolray"
mkdir -p validation/results
status=0
python3 - <<'PY' > validation/results/commands.txt
import json
for c in json.load(open("validation/cases.json"))["cases"]:
    print(c["lens"], c["trials"], c["seed"], c["chord_mm"], c["fields"], c["pupil"], c["spot_bound_um"])
PY
while read -r lens trials seed chord fields pupil spot; do
  echo "== $lens: nominal + $trials patterns, chord $chord mm"
  "$bin" validate "$lens" --embree --trials "$trials" --seed "$seed" --chord "$chord" \
    --fields "$fields" --pupil "$pupil" --spot-bound-um "$spot" \
    --json "validation/results/$lens.json" "$@" || status=1
done < validation/results/commands.txt
exit $status
