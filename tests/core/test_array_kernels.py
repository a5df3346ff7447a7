"""Array kernels (mps_core.codegen.array_kernels): an exact kernel's code on one array a number,
element by element what the float kernel gives for each scene (to round-off)."""

from __future__ import annotations

import math

import numpy as np
import pytest
from kernel_cases import scene_engines, state

from mps_core.codegen.array_kernels import ArrayBranchChanged, array_kernel
from mps_core.codegen.exact_kernels import exact_kernel
from mps_core.derivatives.tracing import BranchChanged
from mps_core.errors import ChartDomainError

MECH, CONTROLS, ENGINE, _ = scene_engines("press-cycle", "autodiff")
VIEWS = [(s, v) for s in ("free", "locked", "held") for v in MECH.views(s) if "~" not in v.name]


def _flat(out) -> list:
    """A kernel's return as one list of numbers (A a float or a tuple)."""
    flat = []
    for part in out:
        flat.extend(part if isinstance(part, (list, tuple)) else [part])
    return flat


def _a_kernel(view):
    """(u, w, the exact kernel traced there): the first state of a coarse grid that is in the
    view's domain."""
    for u in (0.4, 1.2, 2.0, 2.8, -0.4, -1.2, -2.0, -2.8):
        for w in (0.05, -0.2, 0.3, -0.4):
            try:
                kernel = exact_kernel(ENGINE, view, np.array(state(view, u, w)))
            except ChartDomainError:
                continue
            assert kernel is not None
            return u, w, kernel
    raise AssertionError(f"no state of the grid in {view.name}'s domain")


@pytest.mark.parametrize("k", range(len(VIEWS)), ids=[f"{s}-{v.name}" for s, v in VIEWS])
def test_an_array_kernel_gives_each_element_what_the_float_kernel_gives(k):
    structure, view = VIEWS[k]
    CONTROLS.structure = structure
    rng = np.random.default_rng(k)
    u0, w0, kernel = _a_kernel(view)
    qs, vs = [], []  # states on the kernel's branch (where its guards hold)
    for u, w in zip(rng.uniform(-0.1, 0.1, 12), rng.uniform(-0.05, 0.05, 12)):
        q, v = state(view, u0 + u, w0 + w), list(rng.uniform(-10.0, 10.0, view.n))
        try:
            kernel(*q, *v)
        except (BranchChanged, ChartDomainError):
            continue
        qs.append(q)
        vs.append(v)
    assert len(qs) >= 4
    arrays = array_kernel(kernel)(*np.array(qs).T, *np.array(vs).T)
    # without A and h (what a batch does not read): None there, the rest the same
    pruned = array_kernel(kernel, drop=(3, 4))(*np.array(qs).T, *np.array(vs).T)
    assert pruned[3] is None and pruned[4] is None
    for a, b in zip(
        _flat([p for j, p in enumerate(pruned) if j not in (3, 4)]), _flat(arrays[:3] + arrays[5:])
    ):
        assert np.array_equal(np.broadcast_to(a, (len(qs),)), np.broadcast_to(b, (len(qs),)))
    got = [np.broadcast_to(x, (len(qs),)) for x in _flat(arrays)]
    for i, (q, v) in enumerate(zip(qs, vs)):
        want = _flat(kernel(*q, *v))
        assert len(want) == len(got)
        # the same operations; numpy's cos, sin and sqrt may differ from math's in the last
        # bit on some processors (vectorised implementations)
        scale = max(1.0, max(abs(x) for x in want))
        assert np.allclose([x[i] for x in got], want, rtol=1e-12, atol=1e-12 * scale)


def test_a_scene_off_the_branch_fails_the_array_kernels_guard():
    """The (phi, psi) chart's square root: at ψ = 90°, φ = −90° the rod cannot reach (l3 + l1
    > l2): the float kernel calls the position function, which raises; the array kernel,
    with that scene among others, raises ArrayBranchChanged."""
    CONTROLS.structure = "free"
    view = next(v for v in MECH.views("free") if v.name.startswith("phi-psi"))
    kernel = exact_kernel(ENGINE, view, np.array([0.4, 0.1]))
    ak = array_kernel(kernel)
    q0, q1 = np.array([0.4, -math.pi / 2]), np.array([0.1, math.pi / 2])
    zeros = np.zeros(2)
    with pytest.raises(ArrayBranchChanged):
        ak(q0, q1, zeros, zeros)
    ak(q0[:1], q1[:1], zeros[:1], zeros[:1])  # the other scene alone: no guard fails
