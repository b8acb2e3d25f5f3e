"""The suite's topics, as the recorder records them by default (no rclpy)."""

#: The suite's topics (relative to the recorder's namespace; '/x' absolute) and types.
KNOWN_TOPICS = {
    'joint_states': 'sensor_msgs/msg/JointState',
    # The true state beside the measured joint_states (published only with sensor or
    # actuator effects on: the simulator's position_noise, ..., actuation_delay, or a
    # disturbance scenario: its effort is then the applied torque, motor plus push).
    'simulator/true_joint_states': 'sensor_msgs/msg/JointState',
    # Pushes and faults (arm_dynamics.disturbance): one status per start or end of one
    # (values time_ns, kind, edge, label), and the live pushes sent to the simulator.
    'simulator/events': 'diagnostic_msgs/msg/DiagnosticStatus',
    'simulator/push': 'geometry_msgs/msg/WrenchStamped',
    'effort_controller/commands': 'std_msgs/msg/Float64MultiArray',
    'arm_controller/reference': 'sensor_msgs/msg/JointState',
    'arm_controller/joint_trajectory': 'trajectory_msgs/msg/JointTrajectory',
    'arm_controller/trajectory_status': 'diagnostic_msgs/msg/DiagnosticStatus',
    # As joint_trajectory_controller's: reference, feedback, error and output per command
    # (the controller publishes it only while someone subscribes: the recorder does).
    'arm_controller/controller_state': 'control_msgs/msg/JointTrajectoryControllerState',
    'goal_pose': 'geometry_msgs/msg/PoseStamped',
    'planner/path': 'nav_msgs/msg/Path',
    'markers': 'visualization_msgs/msg/MarkerArray',
    'robot_description': 'std_msgs/msg/String',
    # The visualizer's frames (as robot_state_publisher's): the movable joints per joint
    # state, and the fixed ones once (transient local).
    'tf': 'tf2_msgs/msg/TFMessage',
    'tf_static': 'tf2_msgs/msg/TFMessage',
    'clock': 'rosgraph_msgs/msg/Clock',
    '/diagnostics': 'diagnostic_msgs/msg/DiagnosticArray',
}
#: Known topics whose publishers are transient local (latched).
LATCHED = frozenset({'planner/path', 'arm_controller/trajectory_status', 'robot_description',
                     'tf_static'})
DEFAULT_TOPICS = list(KNOWN_TOPICS)
