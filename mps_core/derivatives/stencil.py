"""The central-difference stencil of the partial-system method: the configurations at which a
chart's positions are evaluated for the velocity analogs and the mass matrix's derivatives."""

from __future__ import annotations

from functools import cache

import numpy as np


@cache
def stencil(n: int) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Offsets (in units of Δ) of the central-difference stencil for n coordinates.

    Returns ``(offsets, plus, minus)``: ``offsets`` is (S, n); for each base point
    b ∈ [q, q+Δe_1, q−Δe_1, …, q+Δe_n, q−Δe_n] and coordinate i, ``plus[b, i]`` and
    ``minus[b, i]`` index the stencil points b ± Δe_i. The base points are the stencil's
    first 1 + 2n points, in that order.
    """
    eye = np.eye(n, dtype=int)
    pts = [tuple([0] * n)]
    for i in range(n):
        pts += [tuple(eye[i]), tuple(-eye[i])]
    for i in range(n):
        pts += [tuple(2 * eye[i]), tuple(-2 * eye[i])]
    for i in range(n):
        for j in range(i + 1, n):
            for si in (1, -1):
                for sj in (1, -1):
                    pts.append(tuple(si * eye[i] + sj * eye[j]))
    index = {p: k for k, p in enumerate(pts)}
    bases = [np.zeros(n, dtype=int)]
    for i in range(n):
        bases += [eye[i], -eye[i]]
    plus = np.array([[index[tuple(b + eye[i])] for i in range(n)] for b in bases])
    minus = np.array([[index[tuple(b - eye[i])] for i in range(n)] for b in bases])
    return np.array(pts, dtype=float), plus, minus


__all__ = ["stencil"]
