"""arm_sim, the user-facing top layer: the ``arm-sim`` CLI, the demo, the node-process
launcher, the client helpers and the composed executable.

It stands on everything else (``arm_common`` base, then ``arm_dynamics``, ``arm_control``,
``arm_planner``, ``arm_bag``); nothing imports it back (``test/test_layers.py``).
``arm_sim.launcher`` is ROS-free.
"""
