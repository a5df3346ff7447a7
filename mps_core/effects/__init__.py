"""Effects: the forces a scene asks for, one small unit each."""

from .base import Effect, Loads
from .gravity import Gravity
from .motor import MOTOR_PRESETS, Motor, MotorData

__all__ = ["Effect", "Loads", "Gravity", "Motor", "MotorData", "MOTOR_PRESETS"]
