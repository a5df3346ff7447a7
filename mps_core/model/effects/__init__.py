"""Effects: the forces a scene asks for, one small unit each."""

from .base import Effect, Loads
from .blanking import Blanking
from .controls import Controls
from .cylinders import DisengageCylinder, EngageCylinder, Latch
from .friction import GuideFriction, JointFriction
from .gravity import Gravity
from .motor import MOTOR_PRESETS, Motor, MotorData
from .springs import RetentionSprings, SliderDamper
from .top_stop import TopStop

__all__ = [
    "Effect",
    "Loads",
    "Controls",
    "Gravity",
    "Motor",
    "MotorData",
    "MOTOR_PRESETS",
    "RetentionSprings",
    "SliderDamper",
    "TopStop",
    "EngageCylinder",
    "DisengageCylinder",
    "Latch",
    "Blanking",
    "JointFriction",
    "GuideFriction",
]
