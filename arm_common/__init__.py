"""arm_common: the small base every arm_sim node stands on (the ROS-glue layer).

* :mod:`arm_common.params` -- :class:`ParamSpec` (default, unit, range, validation) and
  ``-p name:=value`` parsing; ROS-free.
* :mod:`arm_common.throttle` -- log/report throttling; ROS-free.
* :mod:`arm_common.node` -- the rclpy helpers the node modules share: parameters declared
  from specs, :class:`~arm_common.node.Diagnostics`, ``run_node`` (the Jazzy ``main()``).

It imports nothing else of arm_sim: the maths packages (``arm_dynamics``, ``arm_control``,
``arm_planner``, ``arm_bag``) sit above it, and the user-facing ``arm_sim`` package (CLI,
demo, launcher, client) on top. ``test/test_layers.py`` keeps it so.
"""
