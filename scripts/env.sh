# Source this to use the project's ROS 2 environment in a shell: `. scripts/env.sh`
_root=$(cd "$(dirname "${BASH_SOURCE[0]}")/.." && pwd)
export VIRTUAL_ENV="$_root/.venv"
export PATH="$_root/.venv/bin:$PATH"
export AMENT_PREFIX_PATH="$_root/ros2_ws/install/magtune_ros:$_root/.venv${AMENT_PREFIX_PATH:+:$AMENT_PREFIX_PATH}"
_sp="$_root/ros2_ws/install/magtune_ros/lib/python3.11/site-packages"
[ -d "$_sp" ] && export PYTHONPATH="$_sp${PYTHONPATH:+:$PYTHONPATH}"
unset _root _sp
