"""The unknown inputs a tracker estimates, as an effect on the nominal model.

Two loads no sensor of a press measures, each a state of the estimator (a random walk):

* the **process force** ``F_p`` on the slider along the guide (x, up: the blanking force the
  part gives the punch); the die on the bed receives −F_p, so the force closes inside the frame;
* the **load torque** ``tau_b`` on the crank: what the nominal model misses on the drive side
  (friction, the motor off its catalogue); the frame receives −tau_b through the bearing.

Their generalized force is Q = F_p·∂x_C/∂q + tau_b·∂φ/∂q (virtual work, contract §4). The values
change at every measurement, so they are read from a list changed in place (no assignment: the
engine's generated code would be made again at each): a ``live`` effect, which the fused
evaluation reads at each call (:func:`~mps_core.codegen.fused_kernels.fused_kernel`). Any other
tracer meets a float of the state in :meth:`UnknownInputs.loads` and keeps the general path
(never traced in with stale values).
"""

from __future__ import annotations

from typing import Any

from ..model.effects.base import Effect, Loads

__all__ = ["UnknownInputs"]


class UnknownInputs(Effect):
    """Apply the estimated process force on the slider and load torque on the crank."""

    kind = "unknown_inputs"
    live = True

    def __init__(self, name: str | None = None) -> None:
        super().__init__(name)
        #: [process force on the slider along x (N), load torque on the crank (N·m)]
        self.values: list[float] = [0.0, 0.0]
        self.acts_on = ("slider", "crank")

    def set(self, force: float, torque: float) -> None:
        """Set the process force (N) and the load torque (N·m) applied from now on."""
        self.values[0] = float(force)
        self.values[1] = float(torque)

    def loads(self, t: float, kin: Any) -> Loads:
        """Return the force on the slider at C and the torque on the crank, with their
        reactions on the frame."""
        float(kin.xy("C")[0])  # a float of the state: keeps the law off a tracer's constants
        return self.live_loads(t, kin, self.values)

    def live_loads(self, t: float, kin: Any, values: Any) -> Loads:
        """Return :meth:`loads` at ``values`` (the process force, the load torque)."""
        f, m = values
        return Loads(
            forces=[("slider", "C", f, 0.0)],
            torques=[("crank", m)],
            frame=[("frame", "C", -f, 0.0), ("frame", -m)],
        )
