# Source me (bash): the environment m4k builds, tests and runs in.
# Real ROS 2 Jazzy when /opt/ros/jazzy exists (unless M4K_USE_WHEELS=1), else the wheels venv.
# Then the workspace overlay when it has been built.
_m4k_root=$(cd "$(dirname "${BASH_SOURCE[0]}")/.." && pwd)
if [[ -f /opt/ros/jazzy/setup.bash && "${M4K_USE_WHEELS:-0}" != 1 ]]; then
  # shellcheck disable=SC1091
  set +u; source /opt/ros/jazzy/setup.bash; set -u 2>/dev/null || true
fi
export VIRTUAL_ENV=$_m4k_root/.venv
export PATH=$VIRTUAL_ENV/bin:$PATH
if [[ ! -f /opt/ros/jazzy/setup.bash || "${M4K_USE_WHEELS:-0}" == 1 ]]; then
  # The wheels install ament/rosidl CMake configs and the ament index into the venv prefix.
  export CMAKE_PREFIX_PATH=$VIRTUAL_ENV${CMAKE_PREFIX_PATH:+:$CMAKE_PREFIX_PATH}
  export AMENT_PREFIX_PATH=$VIRTUAL_ENV${AMENT_PREFIX_PATH:+:$AMENT_PREFIX_PATH}
fi
if [[ -f $_m4k_root/install/local_setup.bash ]]; then
  # shellcheck disable=SC1091
  set +u; source "$_m4k_root/install/local_setup.bash"; set -u 2>/dev/null || true
fi
unset _m4k_root
