"""Recording and analysing arm_sim runs as rosbag2 bags (MCAP storage).

Pure modules (no rclpy): :mod:`arm_bag.msgdefs` (schemas, type hashes and QoS text for
ROS 2 message types, from the installed ``.msg`` files), :mod:`arm_bag.writer` (an MCAP +
``metadata.yaml`` writer), :mod:`arm_bag.reader` (fast bag reader with bulk numpy decoding),
:mod:`arm_bag.cdr` (CDR decoders), :mod:`arm_bag.metrics`, :mod:`arm_bag.analysis`,
:mod:`arm_bag.report`, :mod:`arm_bag.plot` and :mod:`arm_bag.cli` (``arm-sim analyze``).
The ``recorder`` node lives in :mod:`arm_bag.recorder_node`, the only module importing rclpy.
"""
