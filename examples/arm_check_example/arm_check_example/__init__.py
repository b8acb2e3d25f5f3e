"""A computed-torque controller for arm_sim's 2-R arm, written only against its topics."""
