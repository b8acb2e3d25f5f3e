"""``composed``: the simulator and the controller in one process, spun by one executor.

The same two nodes as ``simulator`` and ``controller`` (same parameters, topics, services and
/diagnostics: statuses ``simulator: <task>`` and ``controller: <task>``, each node its own; each
reads its own section of a params file), composed the way ros2_control
runs a controller in the hardware's update loop: a state goes to the controller and its
command comes back without leaving the process or waking another one. Measured in
``bench/bench_loop.py`` side by side with the two processes, this is what holds real time at
1 kHz control. ``arm-sim bringup --composed`` starts it instead of the two processes.
"""

from __future__ import annotations

from arm_common.node import run_node
from arm_control.controller_node import CONTROL_PARAMS, ControllerNode
from arm_control.controller_node import SUMMARY as CONTROLLER_SUMMARY
from arm_dynamics.robot import ROBOT_PARAMS
from arm_dynamics.simulator_node import SIM_PARAMS, SimulatorNode
from arm_dynamics.simulator_node import SUMMARY as SIMULATOR_SUMMARY

SUMMARY = f'''
The simulator and the controller composed in one process with one executor (nodes
"simulator" and "controller": parameters of both, set per node with a params file's
/**/simulator and /**/controller sections).

simulator:{SIMULATOR_SUMMARY}
controller:{CONTROLLER_SUMMARY}'''


def _both() -> list:
    return [SimulatorNode(), ControllerNode()]


def main(args: list[str] | None = None) -> int:
    specs = ROBOT_PARAMS + SIM_PARAMS + tuple(s for s in CONTROL_PARAMS
                                               if s.name not in {p.name for p in SIM_PARAMS})
    return run_node(_both, prog='composed', summary=SUMMARY, specs=specs, args=args)


if __name__ == '__main__':
    raise SystemExit(main())
