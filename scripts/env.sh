# Source this to use the project's ROS 2 environment in a shell: `. scripts/env.sh`
_root=$(cd "$(dirname "${BASH_SOURCE[0]}")/.." && pwd)
export VIRTUAL_ENV="$_root/.venv"
export PATH="$_root/.venv/bin:$PATH"
export AMENT_PREFIX_PATH="$_root/.venv${AMENT_PREFIX_PATH:+:$AMENT_PREFIX_PATH}"
# every colcon-built package of ros2_ws (magtune_ros, ...)
for _pkg in "$_root"/ros2_ws/install/*/; do
  [ -f "$_pkg/share/ament_index/resource_index/packages/$(basename "$_pkg")" ] || continue
  export AMENT_PREFIX_PATH="${_pkg%/}:$AMENT_PREFIX_PATH"
  # typesupport libraries of the interface packages (tf2_msgs, rosbag2_interfaces)
  ls "${_pkg}lib/"*.so >/dev/null 2>&1 && export LD_LIBRARY_PATH="${_pkg}lib${LD_LIBRARY_PATH:+:$LD_LIBRARY_PATH}"
  _sp="${_pkg}lib/python3.11/site-packages"
  [ -d "$_sp" ] && export PYTHONPATH="$_sp${PYTHONPATH:+:$PYTHONPATH}"
  # colcon --symlink-install leaves only an .egg-link (no easy-install.pth): put its target
  # (ros2_ws/build/<pkg>, holding the .egg-info with the entry points) on the path too
  for _el in "$_sp"/*.egg-link; do
    [ -f "$_el" ] && export PYTHONPATH="$(head -n1 "$_el"):$PYTHONPATH"
  done
done
unset _root _sp _pkg _el
