"""Mechanisms: position functions of their charts, and their bodies."""

from .press import PressGeometry, PressMechanism, BodyData, SEED_BODIES

__all__ = ["PressGeometry", "PressMechanism", "BodyData", "SEED_BODIES"]
