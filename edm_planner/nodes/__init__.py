"""ROS 2 adapters (rclpy): parameters in, messages <-> numpy, core calls, results out."""
