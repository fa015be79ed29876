# The ROS 2 underlay of this checkout's .venv (ROS 2 Jazzy from PyPI wheels): for a colcon workspace
# built and run on top of the wheels, it stands for `source /opt/ros/jazzy/setup.bash` of a real install.
#
#   source tools/ros_underlay.bash [VENV]      # bash; VENV defaults to this checkout's .venv
#
# It activates the venv (its python3 and colcon first on PATH: colcon builds with the Python that holds
# the ROS wheels, and the nodes' shebang names it), points AMENT_PREFIX_PATH at it, and puts the venv's
# ROS libraries on LD_LIBRARY_PATH itself, in a fixed order, with ros-wheels-bootstrapper's guard set.
# Why the last: the bootstrapper (a .pth file run at every start of the venv's Python) re-executes the
# interpreter with LD_LIBRARY_PATH rebuilt from a Python set, in an order that changes from one process
# to the next. A workspace's install/<pkg>/lib, which install/setup.bash puts first, then lands after
# .venv/lib in about half the starts; for edm_planner_msgs, which .venv holds too (make setup builds it
# there), such a process imported the workspace's Python module with the venv's copy of its C libraries
# (as its /proc/<pid>/maps showed).
# With the order set here, install/setup.bash's prefixes come first, as on a real install.

_ros_underlay_venv=${1:-"$(cd "$(dirname "${BASH_SOURCE[0]}")/.." && pwd)/.venv"}
if [ ! -x "$_ros_underlay_venv/bin/python" ]; then
  echo "ros_underlay: no venv at $_ros_underlay_venv (run make setup)" >&2
  unset _ros_underlay_venv
  return 1
fi
# shellcheck disable=SC1091
source "$_ros_underlay_venv/bin/activate"
export AMENT_PREFIX_PATH=$VIRTUAL_ENV${AMENT_PREFIX_PATH:+:$AMENT_PREFIX_PATH}
# the directories the bootstrapper adds: the venv's lib/ and the wheels' vendored ros_*.libs
_ros_underlay_libs=$VIRTUAL_ENV/lib
for _ros_underlay_d in "$VIRTUAL_ENV"/lib/python3*/site-packages/ros_*.libs; do
  [ -d "$_ros_underlay_d" ] && _ros_underlay_libs=$_ros_underlay_libs:$_ros_underlay_d
done
export LD_LIBRARY_PATH=$_ros_underlay_libs${LD_LIBRARY_PATH:+:$LD_LIBRARY_PATH}
export _ROS_WHEELS_BOOTSTRAP_COMPLETE=1
unset _ros_underlay_venv _ros_underlay_libs _ros_underlay_d
