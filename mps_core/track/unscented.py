"""The unscented prediction of a tracker's state, kept to measure the choice of filter by.

With ``prediction = "unscented"`` (:class:`~mps_core.track.settings.TrackSettings`) the
covariance goes through the model's run by sigma points instead of the step map's Jacobian:
2m + 1 points (m the state's size; α = 1, β = 2, κ = 0: the centre point carries no weight in the
covariance, the others lie at ±√m standard deviations along the covariance's eigenvectors), each
run from the step's start (the run rewound to a checkpoint, restarted at the point, advanced to
the stamp). The mean is the centre point's run, so that the estimate's structure and events are
those of one run. The measurement update is the tracker's. Where a point ends in another chart
view or structure than the centre, or leaves its chart, the step is left to the Jacobian.

The points run one after another through the model's own run (events, charts and structures as
the simulation has them): the engine evaluates one state at a time, so they are not one numpy
batch (that would take a second, vectorised model of every structure). docs/tracking.md
compares the two predictions.
"""

from __future__ import annotations

from typing import Any, Protocol

import numpy as np

from ..errors import MpsError
from . import lags
from .settings import TrackSettings
from .unknown_inputs import UnknownInputs

__all__ = ["Predicted", "unscented_step"]


class Predicted(Protocol):
    """What the unscented prediction reads of a tracker (the tracker is one)."""

    sim: Any
    x: np.ndarray
    P: np.ndarray
    settings: TrackSettings
    inputs: UnknownInputs

    def process_noise(self, view: Any, structure: str, dt: float) -> np.ndarray:
        """Return the discrete process noise over a step of dt."""
        ...


class _Disagree(Exception):
    """The sigma points ended in different chart views or structures."""


def unscented_step(tracker: Predicted, t1: float) -> tuple[np.ndarray, np.ndarray] | None:
    """Return the predicted (x, P) at t1 by sigma points, the run left at the centre point's
    end; None (the run as it was) where the points do not agree on the view or one fails."""
    sim = tracker.sim
    t0 = sim.t
    view0, structure0 = sim.view, sim.structure
    n = view0.n
    x, lag = tracker.x, tracker.settings.force_lag
    m = len(x)
    start = sim.checkpoint()
    inputs = list(tracker.inputs.values)
    vals, vecs = np.linalg.eigh(0.5 * (tracker.P + tracker.P.T))
    root = vecs * np.sqrt(np.maximum(vals, 0.0) * m)
    points = [x + root[:, j] for j in range(m)] + [x - root[:, j] for j in range(m)] + [x]
    ends = []
    try:
        for p in points:  # the centre last: the run is left at its end
            sim.restore(start)
            tracker.inputs.set(float(p[2 * n]), float(p[2 * n + 1]))
            sim.restart_at(p[:n], p[n : 2 * n])
            x_C0 = float(sim.solver.current.kin.xy("C")[0])
            sim.advance_to(t1)
            if sim.view is not view0 or sim.structure != structure0:
                raise _Disagree
            e1 = sim.solver.current
            F, tau, W, s_m = p[2 * n : 2 * n + 4]
            W = W - F * (float(e1.kin.xy("C")[0]) - x_C0)
            lagged = lags.shifted(p, n, lag)
            ends.append(np.concatenate([e1.q, e1.qd, [F, tau, W, s_m], lagged]))
    except (_Disagree, MpsError, ArithmeticError, ValueError):
        sim.restore(start)
        tracker.inputs.set(*inputs)
        e = sim.solver.current
        sim.restart_at(e.q, e.qd)
        return None
    Y = np.array(ends)
    mean = Y[-1]
    D = Y[:-1] - mean
    P = (D.T @ D) / (2 * m) + tracker.process_noise(view0, structure0, t1 - t0)
    return mean, P
