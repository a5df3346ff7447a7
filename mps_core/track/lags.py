"""The fixed-lag part of a tracker's state: the last steps' states and forces, kept as states.

A force acting over one step shows in the crank angle only at the next samples, so the force of
a step some samples back, and the state the step started from, are known far better than the
present ones (a fixed-lag smoother by state augmentation). The state
``x = (q, q̇, F_p, tau_b, W, s_m, slot 1, …, slot L)`` holds, in slot j, the coordinates and rates at
the start of the step j steps back and the process force over that step: ``(q, q̇, F_p)``, 2n + 1
numbers in the present chart view. At each step slot 1 takes the step's start and force and the
others move one slot back. Where the chart view changes (n or the coordinates change) the slots
start again as copies of the present state, fully correlated with it.
"""

from __future__ import annotations

import functools

import numpy as np

__all__ = ["core_size", "restart", "shifted", "slot", "step_rows"]


def core_size(n: int) -> int:
    """Return the size of the state before its slots: (q, q̇, F_p, tau_b, W, s_m)."""
    return 2 * n + 4


def slot(n: int, j: int) -> slice:
    """Return where slot ``j`` (1-based) lies in the state: its (q, q̇, F_p)."""
    start = core_size(n) + (j - 1) * (2 * n + 1)
    return slice(start, start + 2 * n + 1)


def shifted(x: np.ndarray, n: int, lag: int) -> np.ndarray:
    """Return the slots after a step from state ``x``: its (q, q̇, F_p) in slot 1, the others
    one slot back."""
    return x[_shifted_index(n, lag)]


@functools.cache
def _shifted_index(n: int, lag: int) -> np.ndarray:
    """Return where :func:`shifted` takes each of its numbers from in the state (read-only): the
    slots after a step are ``x[_shifted_index(n, lag)]``."""
    if lag == 0:
        out = np.zeros(0, dtype=np.intp)
    else:
        k = core_size(n)
        out = np.array([*range(2 * n + 1), *range(k, k + (lag - 1) * (2 * n + 1))], dtype=np.intp)
    out.flags.writeable = False
    return out


def step_rows(Phi: np.ndarray, n: int, lag: int) -> None:
    """Fill the slots' rows of a step's Φ (the core's rows filled already)."""
    if lag == 0:
        return
    k = core_size(n)
    w = 2 * n + 1
    for i in range(2 * n + 1):  # slot 1 takes the step's start: (q, q̇, F_p)
        Phi[k + i, i] = 1.0
    for j in range(1, lag):  # slot j + 1 takes slot j
        Phi[k + j * w : k + (j + 1) * w, k + (j - 1) * w : k + j * w] = np.eye(w)


def restart(x: np.ndarray, P: np.ndarray, n: int, lag: int) -> tuple[np.ndarray, np.ndarray]:
    """Return (x, P) with every slot a copy of the present (q, q̇, F_p), fully correlated with
    it (the slots start again: a change of chart view or structure)."""
    k = core_size(n)
    core = x[:k]
    pick = np.zeros((2 * n + 1, k))
    pick[: 2 * n, : 2 * n] = np.eye(2 * n)
    pick[2 * n, 2 * n] = 1.0
    S = np.vstack([np.eye(k)] + [pick] * lag)
    return S @ core, S @ P[:k, :k] @ S.T
