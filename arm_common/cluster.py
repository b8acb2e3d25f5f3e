"""Running pure work on a Dask distributed cluster (no rclpy; dask imported only here).

Used by ``arm-sim sweep --dask`` and ``arm-sim analyze --dask``. Dask is an optional extra
(``pip install 'arm_sim[dask]'``); nothing else in arm_sim imports it.
"""

from __future__ import annotations

from collections.abc import Callable, Sequence
from typing import Any

CONNECT_TIMEOUT = '10s'  # to reach the scheduler


class ClusterError(RuntimeError):
    """Dask is missing or the scheduler cannot be reached (the message says which)."""


def dask_map(address: str, fn: Callable[[Any], Any], items: Sequence[Any],
             on_result: Callable[[int, Any], None] | None = None) -> list[Any]:
    """``[fn(x) for x in items]``, computed on the Dask cluster at ``address``.

    ``fn`` must be importable on the workers (a module-level function of arm_sim).
    ``on_result(i, result)`` is called as each result arrives (any order); the returned
    list is in the order of ``items``. An exception raised by ``fn`` is raised here.
    """
    try:
        from distributed import Client, as_completed
    except ImportError:
        raise ClusterError("--dask needs dask and distributed: pip install 'arm_sim[dask]' "
                           '(or dask distributed)') from None
    try:
        client = Client(address, timeout=CONNECT_TIMEOUT)
    except (OSError, TimeoutError, ValueError) as exc:
        raise ClusterError(f'cannot reach the Dask scheduler at {address}: {exc}') from None
    results: list[Any] = [None] * len(items)
    try:
        futures = client.map(fn, list(items), pure=False)
        index = {f.key: i for i, f in enumerate(futures)}
        for f in as_completed(futures):
            i = index[f.key]
            results[i] = f.result()
            if on_result is not None:
                on_result(i, results[i])
    finally:
        client.close()
    return results
