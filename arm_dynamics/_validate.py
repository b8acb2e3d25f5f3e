"""Argument checks shared by the ROS-free modules: every error names the bad argument."""

from __future__ import annotations

import math
from collections.abc import Sequence

import numpy as np


def finite_scalar(name: str, value: object, *, minimum: float | None = None,
                  strict: bool = False) -> float:
    """Return ``value`` as a float, checking it is finite and above ``minimum``.

    Raises
    ------
    ValueError
        Naming ``name`` and the offending value.
    """
    try:
        x = float(value)  # type: ignore[arg-type]
    except (TypeError, ValueError):
        raise ValueError(f'{name} must be a number, got {value!r}') from None
    if not math.isfinite(x):
        raise ValueError(f'{name} must be finite, got {x!r}')
    if minimum is not None:
        if strict and not x > minimum:
            raise ValueError(f'{name} must be > {minimum:g}, got {x!r}')
        if not strict and not x >= minimum:
            raise ValueError(f'{name} must be >= {minimum:g}, got {x!r}')
    return x


def finite_tuple(name: str, value: object, size: int, *, minimum: float | None = None,
                 strict: bool = False) -> tuple[float, ...]:
    """Return ``value`` as a tuple of ``size`` finite floats (each checked like
    :func:`finite_scalar`)."""
    if isinstance(value, (str, bytes)) or not isinstance(value, (Sequence, np.ndarray)):
        raise ValueError(f'{name} must be a sequence of {size} numbers, got {value!r}')
    if len(value) != size:
        raise ValueError(f'{name} must have {size} elements, got {len(value)}: {value!r}')
    return tuple(finite_scalar(f'{name}[{i}]', v, minimum=minimum, strict=strict)
                 for i, v in enumerate(value))


def step_count(name: str, value: object) -> int:
    """Return ``value`` as an int >= 1 (a number of integration steps)."""
    if isinstance(value, bool) or not isinstance(value, (int, np.integer)) or value < 1:
        raise ValueError(f'{name} must be an integer >= 1, got {value!r}')
    return int(value)


def state_array(name: str, value: object, size: int) -> np.ndarray:
    """Return ``value`` as a float array of shape ``(..., size)`` with finite entries."""
    try:
        arr = np.asarray(value, dtype=float)
    except (TypeError, ValueError):
        raise ValueError(f'{name} must be numeric, got {value!r}') from None
    if arr.ndim == 0 or arr.shape[-1] != size:
        raise ValueError(f'{name} must have shape (..., {size}), got shape {arr.shape}')
    if not np.isfinite(arr).all():
        raise ValueError(f'{name} must be finite, got {value!r}')
    return arr
