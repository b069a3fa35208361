#!/usr/bin/env bash
# `make test`: lint, colcon test of every package, the workspace tests in test/, one summary.
# `make check` (tools/run-tests.sh --check): the same without the end-to-end tier -- the tests
# marked `e2e` (they start the stack, its processes or ROS nodes; every workspace module but the
# static checks listed in test/conftest.py) -- the fast loop while editing; its three tiers run
# side by side.
# Exits non-zero on any failure, and when no test ran at all.
set -uo pipefail
cd "$(dirname "$0")/.."
markers='not hardware'
if [[ ${1:-} == --check ]]; then
  markers='not e2e and not hardware'
elif [[ -n ${1:-} ]]; then
  echo "usage: $0 [--check]" >&2
  exit 2
fi
source tools/env.sh
# Isolation for everything that starts ROS nodes: a random domain, localhost-only discovery.
export ROS_DOMAIN_ID=${ROS_DOMAIN_ID:-$(( (RANDOM % 100) + 1 ))}
export ROS_AUTOMATIC_DISCOVERY_RANGE=LOCALHOST
export M4K_CI=1
rc=0
rm -rf build/*/test_results build/workspace_test   # this run's results only
mkdir -p build/workspace_test

lint() {
  echo "== lint (tools/lint.sh: ruff, then mypy) =="
  tools/lint.sh
}

packages() {
  echo "== colcon test -m '$markers' (ROS_DOMAIN_ID=$ROS_DOMAIN_ID, localhost discovery) =="
  colcon --log-base log test --event-handlers console_cohesion- status- \
    --base-paths src --return-code-on-test-failure \
    --pytest-args -q -p no:cacheprovider -m "$markers"
}

workspace() {
  echo "== workspace tests (test/) -m '$markers' =="
  python -m pytest test -q -p no:cacheprovider -m "$markers" \
    --junitxml=build/workspace_test/test_results/workspace/pytest.xml
}

if [[ $markers == *'not e2e'* ]]; then
  # The unit tiers start no processes of the stack and no ROS nodes, so they run side by
  # side: lint and the workspace tier next to colcon test, whose packages wait on each other
  # (m4k_rt, then m4k_drivers alone) and leave a core idle. Their output follows colcon's.
  out=$(mktemp -d)
  lint >"$out/lint" 2>&1 & lint_pid=$!
  workspace >"$out/workspace" 2>&1 & ws_pid=$!
  packages || rc=1
  wait $lint_pid || rc=1
  cat "$out/lint"
  wait $ws_pid || rc=1
  cat "$out/workspace"
  rm -rf "$out"
else
  # Lint needs no stack: it runs beside the package tier (which leaves a core idle while its
  # packages wait on each other); the end-to-end workspace tier then has the machine alone.
  out=$(mktemp -d)
  lint >"$out/lint" 2>&1 & lint_pid=$!
  packages || rc=1
  wait $lint_pid || rc=1
  cat "$out/lint"
  rm -rf "$out"
  workspace || rc=1
fi

echo "== summary =="
tools/test-summary.sh build || rc=1
[[ $rc -eq 0 ]] && echo 'm4k: all tests passed' || echo 'm4k: TESTS FAILED' >&2
exit $rc
