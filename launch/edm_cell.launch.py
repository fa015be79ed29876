"""The edm_planner cell: the four nodes with their parameters, for ``ros2 launch edm_planner edm_cell.launch.py``.

Arguments: ``params_file`` (default: share/edm_planner/config/edm_cell.yaml, every parameter with its
unit) and ``respawn`` (restart a node that exits, 2 s later; default true: a cell runs around the
clock). Each node runs Fast DDS on loopback UDP when ROS_AUTOMATIC_DISCOVERY_RANGE is
LOCALHOST (edm_planner/ros/dds.py). The ROS 2 wheels this project installs have no ``ros2 launch``:
there ``make demo`` brings the same nodes up with the same parameters file.
"""

import os

from ament_index_python.packages import get_package_share_directory
from launch import LaunchDescription
from launch.actions import DeclareLaunchArgument
from launch.substitutions import LaunchConfiguration
from launch_ros.actions import Node

PACKAGE = "edm_planner"
#: the nodes, in the order they come up (the loader publishes the geometry the others wait for)
NODES = ("geometry_loader", "interference_checker", "trajectory_planner", "axis_bridge")
#: seconds before a node that exited is started again [s] (launch takes a number here, not an argument)
RESPAWN_DELAY = 2.0


def generate_launch_description():
    share = get_package_share_directory(PACKAGE)
    params_file = LaunchConfiguration("params_file")
    respawn = LaunchConfiguration("respawn")
    arguments = [
        DeclareLaunchArgument("params_file", default_value=os.path.join(share, "config", "edm_cell.yaml"),
                              description="parameters of the four nodes (ROS 2 parameters YAML)"),
        DeclareLaunchArgument("respawn", default_value="true", description="restart a node that exits"),
    ]
    nodes = [Node(package=PACKAGE, executable=name, name=name, parameters=[params_file], output="screen",
                  respawn=respawn, respawn_delay=RESPAWN_DELAY, emulate_tty=True)
             for name in NODES]
    return LaunchDescription(arguments + nodes)
