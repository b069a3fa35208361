#!/usr/bin/env bash
# Set up the m4k workspace on this machine, idempotently:
#   * a real ROS 2 Jazzy in /opt/ros/jazzy is used when present (M4K_USE_WHEELS=1 overrides);
#   * otherwise ROS 2 Jazzy comes from pinned PyPI wheels in .venv (requirements.txt), with the
#     two paths the wheels' CMake exports bake in (/opt/python/cp311-cp311/...) rewritten to this
#     interpreter's include directories, inside the venv only (no root needed).
# A second run checks a stamp and returns in well under a second.
set -euo pipefail
cd "$(dirname "$0")/.."
ROOT=$PWD
VENV=$ROOT/.venv
STAMP=$VENV/.m4k-setup-stamp

say() { printf 'm4k setup: %s\n' "$*" >&2; }
die() { printf 'm4k setup: error: %s\n' "$*" >&2; exit 1; }

need_cmd() {  # need_cmd <command> <debian package>
  command -v "$1" >/dev/null 2>&1 || die "'$1' not found -- install it: sudo apt-get install $2"
}

ros_mode=wheels
if [[ -f /opt/ros/jazzy/setup.bash && "${M4K_USE_WHEELS:-0}" != 1 ]]; then
  ros_mode=system
fi

# --- prerequisites: one clear message naming the package, never a traceback -----------------
need_cmd cmake cmake
need_cmd gcc gcc
need_cmd g++ g++
need_cmd make make
PY=""
if [[ $ros_mode == system ]]; then
  PY=$(command -v python3 || true)
else
  for cand in python3.11 python3.12; do
    if command -v "$cand" >/dev/null 2>&1; then PY=$(command -v "$cand"); break; fi
  done
fi
[[ -n $PY ]] || die "Python 3.11 or 3.12 not found (the ROS 2 Jazzy wheels are cp311/cp312) -- install it: sudo apt-get install python3.11 python3.11-venv python3.11-dev"
"$PY" -c 'import venv, ensurepip' 2>/dev/null \
  || die "$PY cannot create virtual environments -- install it: sudo apt-get install python3-venv (or python3.11-venv)"
pyver=$("$PY" -c 'import sys; print("%d.%d" % sys.version_info[:2])')
"$PY" -c 'import sysconfig, os, sys; sys.exit(0 if os.path.exists(os.path.join(sysconfig.get_paths()["include"], "Python.h")) else 1)' \
  || die "Python headers for $pyver not found -- install them: sudo apt-get install python${pyver}-dev"

# The bench's reference tools (m4k_bench.benchlib.system.TOOL_PACKAGES): `make test`'s bench
# smoke test needs them, `make bench`/`soak` compare against them. Installed here as root where
# apt works; otherwise one line saying how (the smoke test then fails naming them).
bench_missing=()
command -v cyclictest >/dev/null 2>&1 || bench_missing+=(rt-tests)
command -v stress-ng >/dev/null 2>&1 || bench_missing+=(stress-ng)
if (( ${#bench_missing[@]} )); then
  if [[ $(id -u) -eq 0 ]] && command -v apt-get >/dev/null 2>&1; then
    say "installing ${bench_missing[*]} (cyclictest, stress-ng: the bench's references)"
    export DEBIAN_FRONTEND=noninteractive
    apt-get install -y -qq "${bench_missing[@]}" >/dev/null 2>&1 \
      || { apt-get update -qq >/dev/null 2>&1 && apt-get install -y -qq "${bench_missing[@]}" >/dev/null 2>&1; } \
      || say "warning: could not install ${bench_missing[*]}: run 'apt-get install ${bench_missing[*]}' as root"
  else
    say "warning: ${bench_missing[*]} missing (the bench smoke test fails without them): sudo apt-get install ${bench_missing[*]}"
  fi
fi

reqs=requirements.txt
[[ $ros_mode == system ]] && reqs=requirements-system-ros.txt
want="$ros_mode $pyver $(sha256sum "$reqs" tools/setup.sh | sha256sum | cut -c1-16)"
if [[ -f $STAMP && "$(cat "$STAMP")" == "$want" ]]; then
  exit 0
fi

# --- the virtual environment ---------------------------------------------------------------
if [[ ! -x $VENV/bin/python ]]; then
  say "creating $VENV ($ros_mode ROS, Python $pyver)"
  if [[ $ros_mode == system ]]; then
    "$PY" -m venv --system-site-packages "$VENV"   # rclpy etc. come from /opt/ros/jazzy
  else
    "$PY" -m venv "$VENV"
  fi
fi
say "installing pinned requirements from $reqs (first run: about a minute)"
"$VENV/bin/python" -m pip install --quiet --disable-pip-version-check -r "$reqs" 2>&1 \
  | grep -v "is ignored: it is neither a file nor a directory" >&2 || true
"$VENV/bin/python" -m pip check >/dev/null 2>&1 || say "warning: 'pip check' reports conflicts"
"$VENV/bin/python" -c 'import yaml, serial, smbus2, periphery, numpy, pytest, websockets' \
  || die "the requirements did not install; see the pip output above"

if [[ $ros_mode == wheels ]]; then
  "$VENV/bin/python" -c 'import rclpy' || die "rclpy did not install from the wheels"
  # The wheels' CMake exports name the build machine's interpreter paths; point them here.
  py_inc=$("$VENV/bin/python" -c 'import sysconfig; print(sysconfig.get_paths()["include"])')
  np_inc=$("$VENV/bin/python" -c 'import numpy; print(numpy.get_include())')
  { grep -rlE '/opt/python/cp3[0-9]+-cp3[0-9]+' "$VENV/share" --include='*.cmake' 2>/dev/null \
    || true; } | while read -r f; do
        sed -i -E \
          -e "s#/opt/python/cp3[0-9]+-cp3[0-9]+/lib/python3\.[0-9]+/site-packages/numpy/_core/include#${np_inc}#g" \
          -e "s#/opt/python/cp3[0-9]+-cp3[0-9]+/include/python3\.[0-9]+#${py_inc}#g" "$f"
      done
  if grep -rqE '/opt/python/cp3' "$VENV/share" --include='*.cmake' 2>/dev/null; then
    die "could not rewrite the wheels' baked-in /opt/python paths under $VENV/share"
  fi
fi
echo "$want" > "$STAMP"
say "ready ($ros_mode ROS 2 Jazzy, Python $pyver)"
