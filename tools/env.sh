# Source me (bash): the environment m4k builds, tests and runs in.
# Real ROS 2 Jazzy when /opt/ros/jazzy exists (unless M4K_USE_WHEELS=1), else the wheels venv.
# Then the workspace overlay when it has been built.
# ROS setup scripts read unset variables: lift nounset while sourcing, restore it after.
case $- in *u*) _m4k_nounset=1; set +u ;; *) _m4k_nounset=0 ;; esac
_m4k_root=$(cd "$(dirname "${BASH_SOURCE[0]}")/.." && pwd)
if [[ -f /opt/ros/jazzy/setup.bash && "${M4K_USE_WHEELS:-0}" != 1 ]]; then
  # shellcheck disable=SC1091
  source /opt/ros/jazzy/setup.bash
fi
export VIRTUAL_ENV=$_m4k_root/.venv
export PATH=$VIRTUAL_ENV/bin:$PATH
if [[ ! -f /opt/ros/jazzy/setup.bash || "${M4K_USE_WHEELS:-0}" == 1 ]]; then
  # The wheels install ament/rosidl CMake configs and the ament index into the venv prefix.
  export CMAKE_PREFIX_PATH=$VIRTUAL_ENV${CMAKE_PREFIX_PATH:+:$CMAKE_PREFIX_PATH}
  export AMENT_PREFIX_PATH=$VIRTUAL_ENV${AMENT_PREFIX_PATH:+:$AMENT_PREFIX_PATH}
fi
if ! command -v ros2 >/dev/null 2>&1; then
  export PATH=$_m4k_root/tools/bin:$PATH   # `ros2 run` by the ament index, without ros2cli
fi
if [[ -f $_m4k_root/install/local_setup.bash ]]; then
  # shellcheck disable=SC1091
  source "$_m4k_root/install/local_setup.bash"
fi
# The console scripts by name too (`bringup`, `rt_stat`, ...), as `ros2 run <pkg> <exe>` would.
for _m4k_pkg in m4k_rt m4k_drivers m4k_bridge m4k_bringup m4k_bench; do
  [[ -d $_m4k_root/install/$_m4k_pkg/lib/$_m4k_pkg ]] \
    && export PATH=$_m4k_root/install/$_m4k_pkg/lib/$_m4k_pkg:$PATH
done
[[ $_m4k_nounset == 1 ]] && set -u
unset _m4k_root _m4k_pkg _m4k_nounset
