#!/usr/bin/env bash
# `make test`: lint, colcon test of every package, the workspace tests in test/, one summary.
# `make check` (tools/run-tests.sh --check): the same without the end-to-end tier -- the tests
# marked `e2e` (they start the stack, its processes or ROS nodes; every workspace module but the
# static checks listed in test/conftest.py) -- the fast loop while editing; its three tiers run
# side by side.
# `make test` runs three streams, each on its own ROS domain and temp directory (in which order:
# at the end of this file; by default the serial one alone, after the other two):
#   serial   the tests marked `serial` (judged on the simulator's physics in wall-clock time:
#            test/conftest.py SERIAL_MODULES, and the package tests marked so), one at a time,
#            at the caller's priority and with its rights (SCHED_FIFO, locked memory); then,
#            confined, the workspace modules in test/conftest.py AFTER_SERIAL;
#   packages lint beside colcon test of every package (less its serial tests), then the
#            workspace modules in AFTER_PACKAGES;
#   e2e      every other workspace module.
# All but serial are confined (`confined` below): in a CPU cgroup of an eighth of the
# default weight, at nice 19, without the right to SCHED_FIFO or locked memory (RLIMIT_RTPRIO
# 0; as root, CAP_SYS_NICE and CAP_IPC_LOCK dropped), so the RT threads of their stacks run
# as ordinary threads and every thread of theirs gets only what the serial stream leaves;
# rt_core reports the refusal (hardening DEGRADED) and runs on. Where no cgroup can be made,
# the serial stream runs alone after the others (AFTER_SERIAL then at the end of packages):
# nice alone does not put a stack that starts its own session below another (autogroup).
# SCHED_IDLE instead of nice 19 starved the confined streams into failures of their own
# (docs/testing.md).
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
  base=$ROS_DOMAIN_ID
  tmp=$(mktemp -d /tmp/m4k-test.XXXXXX)   # short: the runtime dirs' socket paths
  # run_pytest <stream> <pytest args...>: a workspace-style pytest run with its own junit file
  # and its own temp directory (two pytest sessions must not share one).
  run_pytest() {
    local name=$1; shift
    python -m pytest -q -p no:cacheprovider --basetemp="$tmp/$name" \
      --junitxml="build/workspace_test/test_results/$name/pytest.xml" "$@"
  }
  # A CPU cgroup of the lowest weight for the confined streams, where this user may make one
  # (cgroup v2 with the cpu controller, or v1's cpu hierarchy). Nice alone does not order the
  # streams: with autogroup scheduling on (/proc/sys/kernel/sched_autogroup_enabled) a process
  # that starts a session -- every stack the tests start does -- gets a group of its own at
  # nice 0, and a niced stack took half the CPU from the serial stream's (docs/testing.md).
  # A task in a cgroup other than the root is outside autogroup; the cgroup's weight decides.
  # An eighth of the default weight (v2 100, v1 1024): a confined stream still runs beside a
  # serial one that holds both cores (the bench's stress-ng), slowly. At a sixteenth the
  # serial stream passed every run, and a confined test timed out on its own clock in two
  # of four (a doctor's graph, a joint_states message; docs/testing.md).
  CG_WEIGHT_V2=12
  CG_SHARES_V1=128
  cg=''
  make_cgroup() {
    local root
    for root in /sys/fs/cgroup /sys/fs/cgroup/cpu; do
      if [[ -f $root/cgroup.subtree_control ]] && grep -qw cpu "$root/cgroup.subtree_control" \
          && mkdir "$root/m4k-test.$$" 2>/dev/null; then
        cg=$root/m4k-test.$$
        echo "$CG_WEIGHT_V2" >"$cg/cpu.weight" 2>/dev/null && return 0
      elif [[ -f $root/cpu.shares ]] && mkdir "$root/m4k-test.$$" 2>/dev/null; then
        cg=$root/m4k-test.$$
        echo "$CG_SHARES_V1" >"$cg/cpu.shares" 2>/dev/null && return 0
      fi
      [[ -n $cg ]] && rmdir "$cg"
      cg=''
    done
    return 1
  }
  # remove_cgroup: every process the confined streams started has ended (their tests stop what
  # they start); a survivor is named, moved out and counted as a failure.
  remove_cgroup() {
    [[ -n $cg ]] || return 0
    local left
    left=$(cat "$cg/cgroup.procs")
    if [[ -n $left ]]; then
      echo "m4k: processes the confined streams left running:" >&2
      ps -o pid=,args= -p "${left//$'\n'/,}" >&2
      for pid in $left; do echo "$pid" >"$(dirname "$cg")/cgroup.procs" 2>/dev/null; done
      rc=1
    fi
    rmdir "$cg" 2>/dev/null || echo "m4k: could not remove $cg" >&2
  }
  # confined <command...>: run it in the cgroup above (when there is one), at nice 19, without
  # the right to real-time scheduling or locked memory, for it and every process it starts (a
  # lowered hard limit and a dropped bounding-set capability are inherited and cannot be
  # taken back).
  confined() {
    local drop=()
    if (( EUID == 0 )); then
      drop=(setpriv --inh-caps=-sys_nice,-ipc_lock --bounding-set=-sys_nice,-ipc_lock --)
    fi
    [[ -n $cg ]] && echo "$BASHPID" >"$cg/cgroup.procs"
    exec nice -n 19 prlimit --rtprio=0:0 "${drop[@]}" "$@"
  }
  serial_stream() {
    export ROS_DOMAIN_ID=$base
    local r=0
    echo "== serial stream: the tests marked serial, one at a time (-m '$markers and serial') =="
    run_pytest serial test -m "$markers and serial" || r=1
    # The package tests marked serial, by pytest on their files (colcon test skips them).
    local serial_files
    mapfile -t serial_files < <(grep -l 'mark\.serial' src/*/test/test_*.py)
    if (( ${#serial_files[@]} )); then
      run_pytest serial_packages "${serial_files[@]}" -m "$markers and serial" || r=1
    fi
    return $r
  }
  packages_stream() {
    export ROS_DOMAIN_ID=$(( base % 100 + 1 ))
    local r=0
    lint >"$tmp/lint.log" 2>&1 & local lint_pid=$!
    markers="$markers and not serial" packages || r=1
    wait $lint_pid || r=1
    cat "$tmp/lint.log"
    after_stream after_packages 0 'the packages' || r=1
    if [[ -z ${AFTER_SERIAL_LATER:-} ]]; then
      after_stream after_serial 2 'the serial ones' || r=1
    fi
    return $r
  }
  # The workspace modules that wait for a stream: after_stream MARKER DOMAIN_OFFSET WHAT
  # (after_packages 0 'the packages' | after_serial 2 'the serial ones').
  after_stream() {
    export ROS_DOMAIN_ID=$(( (base + $2) % 100 + 1 ))
    echo "== workspace tests after $3 (-m '$markers and not serial and $1') =="
    run_pytest "$1" test -m "$markers and not serial and $1"
  }
  e2e_stream() {
    export ROS_DOMAIN_ID=$(( (base + 1) % 100 + 1 ))
    local m="$markers and not serial and not after_packages and not after_serial"
    echo "== workspace tests (-m '$m') =="
    run_pytest e2e test -m "$m"
  }
  export -f lint packages run_pytest packages_stream e2e_stream after_stream
  export tmp markers base
  # The side-by-side layout is opt-in (M4K_TEST_SIDE_BY_SIDE=1): 14 min 27 s - 15 min 37 s in
  # fresh clones, but in four of seven a confined test failed on its own clock -- each time
  # another one, each fixed (docs/testing.md). The default stays the order CI has passed in.
  if [[ ${M4K_TEST_SIDE_BY_SIDE:-} == 1 ]] && make_cgroup; then
    # All three side by side: the serial stream at the caller's priority in the root group,
    # the packages and e2e streams in the low-weight cgroup, where they get what the serial
    # stack leaves.
    # Three at a time: the serial stream, then (confined) the AFTER_SERIAL modules, beside
    # the packages stream (then the AFTER_PACKAGES modules) and the e2e stream. As a fourth
    # stream from the start those modules starved the confined streams on 2 cores into
    # timeouts (a stack that did not reach speed in 60 s, a pty scan late by 0.5 s: 821a8c7);
    # all of them behind the serial stream took 15 min 3 s (4d6c3f4).
    echo "== three streams side by side; the confined ones in $cg =="
    export AFTER_SERIAL_LATER=1
    (confined bash -c packages_stream) >"$tmp/packages.log" 2>&1 & packages_pid=$!
    (confined bash -c e2e_stream) >"$tmp/e2e.log" 2>&1 & e2e_pid=$!
    serial_stream >"$tmp/serial.log" 2>&1 || rc=1
    (confined bash -c "after_stream after_serial 2 'the serial ones'") >"$tmp/after.log" 2>&1 \
      || rc=1
  else
    # The default, and where no cgroup can be made: the serial stream alone, after the other
    # two (the modules after the packages at the end of the packages stream). Beside them
    # (niced, in
    # sessions of their own) four fresh clones took 11 min 45 s - 14 min 59 s and three of
    # them failed a test on the load (docs/testing.md).
    echo "== the serial stream runs after the confined ones (M4K_TEST_SIDE_BY_SIDE=1: side by side, docs/testing.md) =="
    (confined bash -c packages_stream) >"$tmp/packages.log" 2>&1 & packages_pid=$!
    (confined bash -c e2e_stream) >"$tmp/e2e.log" 2>&1 & e2e_pid=$!
  fi
  wait $packages_pid || rc=1
  echo "== lint and colcon test, then the modules after the packages =="
  cat "$tmp/packages.log"
  wait $e2e_pid || rc=1
  cat "$tmp/e2e.log"
  [[ -f $tmp/after.log ]] && cat "$tmp/after.log"
  remove_cgroup
  if [[ -f $tmp/serial.log ]]; then
    cat "$tmp/serial.log"
  else
    serial_stream || rc=1
  fi
  rm -rf "$tmp"
fi

echo "== summary =="
tools/test-summary.sh build || rc=1
[[ $rc -eq 0 ]] && echo 'm4k: all tests passed' || echo 'm4k: TESTS FAILED' >&2
exit $rc
