"""Simulated-time stamps: the one rule for a valid ``builtin_interfaces/Time`` (pure, no
rclpy). Used by every node's guard of ``/clock`` (:func:`arm_common.node.guard_messages`),
the controller's joint states and the live view's inputs."""

from __future__ import annotations

NS_PER_S = 1_000_000_000
#: builtin_interfaces/Time.sec is an int32.
MAX_STAMP_SEC = 2**31 - 1


def stamp_refusal(sec: object, nanosec: object, what: str = 'header.stamp') -> str | None:
    """Why (``sec``, ``nanosec``) is no valid simulated time stamp, or None: both must be
    integers, ``sec`` in [0, 2^31 - 1] (simulated time starts at 0; builtin_interfaces/Time
    holds an int32) and ``nanosec`` in [0, 1e9) (more is a second and belongs in ``sec``).
    ``what`` names the field in the reason."""
    if isinstance(sec, bool) or not isinstance(sec, int):
        return f'{what}.sec must be an integer, got {sec!r}'
    if isinstance(nanosec, bool) or not isinstance(nanosec, int):
        return f'{what}.nanosec must be an integer, got {nanosec!r}'
    if sec < 0:
        return f'{what} is negative (sec = {sec}): simulated time starts at 0'
    if sec > MAX_STAMP_SEC:
        return (f'{what}.sec = {sec} overflows builtin_interfaces/Time (an int32: at most '
                f'{MAX_STAMP_SEC})')
    if not 0 <= nanosec < NS_PER_S:
        return f'{what}.nanosec = {nanosec} is outside [0, 1e9)'
    return None
