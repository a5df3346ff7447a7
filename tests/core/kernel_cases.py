"""What the kernel tests share: a scene's engines with and without kernels, and states."""

from __future__ import annotations

import numpy as np

from mps_core import load_scene
from mps_core.dynamics.engine import PartialSystems
from mps_core.model.effects.controls import Controls


def scene_engines(name: str, scheme: str):
    """(mechanism, controls, engine with kernels, engine without) for a scene's effects."""
    sc = load_scene(name)
    mech = sc.mechanism()
    effects = sc.build_effects(mech)
    controls = Controls(structure="free", engage_on=True)
    for e in effects:
        if hasattr(e, "use"):
            e.use(controls)
    return (
        mech,
        controls,
        PartialSystems(mech, effects, scheme),
        PartialSystems(mech, effects, scheme, kernels=False),
    )


def state(view, u: float, w: float) -> list:
    """A configuration of a view from two numbers: u for an angle, w for ψ or x_C."""
    names = [c.name for c in view.coordinates]
    q = [u if n != "x_C" else 0.01 + 0.04 * (w + 0.5) for n in names]
    if view.n == 2 and names[1] == "psi":
        q[1] = w
    return q


def close(a, b, scale: float, rtol: float) -> bool:
    return np.abs(np.asarray(a) - np.asarray(b)).max() <= rtol * scale
