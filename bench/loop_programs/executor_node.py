"""Run one arm_sim node with its executor replaced: the ``single`` and ``multi`` variants.

``bench/bench_loop.py --executors single,multi`` starts the simulator and controller
through this file instead of their executables (``Loop._executable`` patches
``arm_sim.launcher.executable``)::

    python bench/loop_programs/executor_node.py VARIANT MODULE [--ros-args ...]

VARIANT is ``single`` (rclpy SingleThreadedExecutor) or ``multi`` (MultiThreadedExecutor);
MODULE is the node's module (``arm_sim.launcher.MODULES``), whose ``main()`` is run with
the remaining arguments, as the node's own executable would. The executor is swapped by
setting ``arm_common.node.EXECUTOR``, which ``run_node()`` looks up at call time
(EventsExecutor as shipped), so no file is edited and the node spins as usual, in
``spin_once`` loops. What the bench measures with it is the loop's speed and timing per
executor; this file only starts the node.
"""

import importlib
import sys

from rclpy import executors

from arm_common import node as ros_common

VARIANTS = {'single': executors.SingleThreadedExecutor,
            'multi': executors.MultiThreadedExecutor}


def main() -> int:
    if len(sys.argv) < 3 or sys.argv[1] not in VARIANTS:
        print(f'usage: {sys.argv[0]} {{{",".join(VARIANTS)}}} MODULE [--ros-args ...]',
              file=sys.stderr)
        return 2
    variant, module = sys.argv[1], sys.argv[2]
    del sys.argv[1:3]  # the node sees only its own arguments
    ros_common.EXECUTOR = VARIANTS[variant]
    return importlib.import_module(module).main()


if __name__ == '__main__':
    sys.exit(main())
