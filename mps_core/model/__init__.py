"""The model: mechanisms (bodies, joints, charts and their position functions,
:mod:`.mechanism`), the press (:mod:`.press`) and the effects, the forces a scene may ask for
(:mod:`.effects`). Objects, not files: a scene (:mod:`mps_core.scene`) builds them."""

from .press import SEED_BODIES, BodyData, PressGeometry, PressMechanism

__all__ = ["PressGeometry", "PressMechanism", "BodyData", "SEED_BODIES"]
