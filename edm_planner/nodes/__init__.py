"""ROS 2 adapters (rclpy): parameters in, messages <-> numpy, core calls, results out."""

from .dds import use_loopback_udp

# Before any rclpy.init of this process: every entry point of ours (nodes, demo, soak, benches) imports this
# package first, so each one runs Fast DDS on loopback UDP, never on shared memory (see dds.py).
DDS_SETUP = use_loopback_udp()
