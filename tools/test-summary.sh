#!/usr/bin/env bash
# The `make test` summary: colcon test-result over BUILD (default build), then one line that
# keeps skipped tests apart from passed ones (a skip is not a pass):
#   m4k: 1208 passed, 5 skipped, 0 failed, 0 errors (1213 collected)
# Exits non-zero on a failure or an error, and when no test passed at all.
set -uo pipefail
base=${1:-build}
rc=0
out=$(colcon test-result --test-result-base "$base" --verbose) || rc=1
printf '%s\n' "$out"
line=$(printf '%s\n' "$out" | grep -E '^Summary: ' | tail -1)
num() { printf '%s\n' "$line" | grep -oE "[0-9]+ $1" | grep -oE '^[0-9]+' || echo 0; }
total=$(num tests); errors=$(num errors); failures=$(num 'failures?'); skipped=$(num skipped)
passed=$(( total - errors - failures - skipped ))
echo "m4k: $passed passed, $skipped skipped, $failures failed, $errors errors ($total collected)"
if (( passed <= 0 )); then
  echo 'm4k: no test passed -- failing' >&2
  rc=1
fi
exit $rc
