"""What the nodes and the programs that drive them share besides messages: the latched QoS, the config directory.

Here, not in a node's module, so that a program of :mod:`edm_planner.nodes.programs` imports no node to reach them.
"""

import pathlib

from ament_index_python.packages import PackageNotFoundError, get_package_share_directory
from rclpy.qos import DurabilityPolicy, QoSProfile, ReliabilityPolicy

#: the QoS of the topics a late joiner must still get (the current geometry, the last plan): kept by the
#: publisher, sent to each new subscriber
LATCHED = QoSProfile(depth=1, durability=DurabilityPolicy.TRANSIENT_LOCAL, reliability=ReliabilityPolicy.RELIABLE)


def config_directory():
    """The installed config directory (share/edm_planner/config), or the source tree's."""
    try:
        return pathlib.Path(get_package_share_directory("edm_planner")) / "config"
    except (PackageNotFoundError, ValueError, KeyError, OSError):
        return pathlib.Path(__file__).resolve().parents[2] / "config"
