"""The suite's topics, as the recorder records them by default (no rclpy)."""

#: The suite's topics (relative to the recorder's namespace; '/x' absolute) and types.
KNOWN_TOPICS = {
    'joint_states': 'sensor_msgs/msg/JointState',
    # The true state beside the measured joint_states (published only with sensor or
    # actuator effects on: the simulator's position_noise, ..., actuation_delay).
    'simulator/true_joint_states': 'sensor_msgs/msg/JointState',
    'effort_controller/commands': 'std_msgs/msg/Float64MultiArray',
    'arm_controller/reference': 'sensor_msgs/msg/JointState',
    'arm_controller/joint_trajectory': 'trajectory_msgs/msg/JointTrajectory',
    'arm_controller/trajectory_status': 'diagnostic_msgs/msg/DiagnosticStatus',
    'goal_pose': 'geometry_msgs/msg/PoseStamped',
    'planner/path': 'nav_msgs/msg/Path',
    'markers': 'visualization_msgs/msg/MarkerArray',
    'robot_description': 'std_msgs/msg/String',
    'clock': 'rosgraph_msgs/msg/Clock',
    '/diagnostics': 'diagnostic_msgs/msg/DiagnosticArray',
}
#: Known topics whose publishers are transient local (latched).
LATCHED = frozenset({'planner/path', 'arm_controller/trajectory_status', 'robot_description'})
DEFAULT_TOPICS = list(KNOWN_TOPICS)
