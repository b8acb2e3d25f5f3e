"""arm_sim glue: parameter specifications, node-process launching, ROS helpers and the CLI.

``arm_sim.params`` and ``arm_sim.launcher`` are ROS-free; ``arm_sim.ros_common`` holds the
rclpy code the nodes share.
"""
