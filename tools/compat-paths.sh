#!/usr/bin/env bash
# Print the extra colcon base paths this machine needs (run with tools/env.sh sourced).
#
# compat/tf2_msgs stands in for tf2_msgs, which is not on PyPI. It is built only when no other
# prefix on AMENT_PREFIX_PATH (a ROS install, an overlay) registers tf2_msgs in the ament index;
# this workspace's own install/ does not count. Where a real one exists, a stand-in left over in
# install/ from an earlier build is removed, so the real package is the one found.
set -euo pipefail
root=$(cd "$(dirname "$0")/.." && pwd)
real=''
IFS=: read -r -a prefixes <<< "${AMENT_PREFIX_PATH:-}"
for p in "${prefixes[@]}"; do
  [[ -z $p || $p == "$root/install" || $p == "$root/install/"* ]] && continue
  if [[ -f $p/share/ament_index/resource_index/packages/tf2_msgs ]]; then real=$p; break; fi
done
if [[ -n $real ]]; then
  if [[ -d $root/install/tf2_msgs ]]; then
    echo "m4k: a real tf2_msgs is installed ($real): removing the stand-in from install/" >&2
    rm -rf "$root/install/tf2_msgs" "$root/build/tf2_msgs"
  fi
else
  echo compat
fi
