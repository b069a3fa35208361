#!/usr/bin/env bash
# `make fuzz`, second half: every property test of every suite (the hypothesis tests that
# `make test` runs derandomized) under the randomized `fuzz` profile (m4k_testing: 20x the
# examples, a fresh seed each run). The seed is printed first and last; replay a failure with
#   make fuzz SEED=<n>      (or: M4K_HYPOTHESIS_PROFILE=fuzz pytest ... --hypothesis-seed=<n>)
set -uo pipefail
cd "$(dirname "$0")/.."
source tools/env.sh
seed=${1:-$(od -An -N4 -tu4 /dev/urandom | tr -d ' ')}
export M4K_HYPOTHESIS_PROFILE=fuzz ROS_AUTOMATIC_DISCOVERY_RANGE=LOCALHOST
echo "m4k fuzz: property tests, hypothesis seed $seed (replay: make fuzz SEED=$seed)"
rc=0
for dir in src/*/test test; do
  python -m pytest "$dir" -q -p no:cacheprovider -m 'hypothesis and not hardware' \
    --hypothesis-seed="$seed"
  code=$?
  [[ $code -eq 0 || $code -eq 5 ]] || rc=1   # 5: no property test in that suite
done
[[ $rc -eq 0 ]] && echo "m4k fuzz: property tests passed (seed $seed)" \
  || echo "m4k fuzz: property tests FAILED -- replay with: make fuzz SEED=$seed" >&2
exit $rc
