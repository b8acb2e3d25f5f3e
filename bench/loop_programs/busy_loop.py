"""A busy loop: one process spinning ``while True: pass`` at normal priority, for ever.

It measures nothing itself: ``bench/bench_loop.py --busy N`` starts N of these
(``busy_loops()``: ``python bench/loop_programs/busy_loop.py``, no arguments, stdio to
/dev/null) for the whole measurement, to load the machine on purpose, and kills them at the
end. Each first asks the kernel to SIGKILL it when its parent dies (``PR_SET_PDEATHSIG``),
so that it dies with the bench even if the bench is killed outright.
"""

import ctypes
import signal

PR_SET_PDEATHSIG = 1

try:
    ctypes.CDLL(None).prctl(PR_SET_PDEATHSIG, signal.SIGKILL)
except Exception:
    pass  # not Linux: the bench still kills the loop itself
while True:
    pass
