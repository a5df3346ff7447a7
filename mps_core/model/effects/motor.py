"""An induction motor driving a body through a reduction: the Kloss torque characteristic."""

from __future__ import annotations

import math
from dataclasses import dataclass

from .base import Effect, Loads


@dataclass(frozen=True)
class MotorData:
    """Catalogue data of an induction motor.

    power_w: rated shaft power P; sync_rpm: synchronous speed; rated_slip: s_n;
    breakdown_ratio: λ = M_k / M_n (breakdown over rated torque).
    """

    power_w: float
    sync_rpm: float
    rated_slip: float
    breakdown_ratio: float
    source: str = ""

    @property
    def omega_sync(self) -> float:
        return self.sync_rpm * 2.0 * math.pi / 60.0

    @property
    def rated_torque(self) -> float:
        """M_n = P / (ω_sync (1 − s_n))."""
        return self.power_w / (self.omega_sync * (1.0 - self.rated_slip))

    @property
    def breakdown_torque(self) -> float:
        return self.breakdown_ratio * self.rated_torque

    @property
    def breakdown_slip(self) -> float:
        """s_k = s_n (λ + √(λ² − 1))."""
        lam = self.breakdown_ratio
        return self.rated_slip * (lam + math.sqrt(lam * lam - 1.0))

    def torque(self, slip: float) -> float:
        """Kloss: M = 2 M_k / (s/s_k + s_k/s), written without the 0/0 at s = 0."""
        sk = self.breakdown_slip
        return 2.0 * self.breakdown_torque * slip * sk / (slip * slip + sk * sk)


#: 4A80B4U3: 1.5 kW, 1500 rpm synchronous, s_n = 5.8 %, M_k/M_n = 2.2 (catalogue of the 4A series)
MOTOR_4A80B4U3 = MotorData(
    power_w=1500.0,
    sync_rpm=1500.0,
    rated_slip=0.058,
    breakdown_ratio=2.2,
    source="4A series induction motor catalogue: 4A80B4U3",
)

MOTOR_PRESETS = {"4A80B4U3": MOTOR_4A80B4U3}


class Motor(Effect):
    """Motor torque on ``body`` (the crank) through a reduction of ratio u and efficiency η.

    Slip ``s = 1 − u·ω_body/ω_sync``; torque on the body ``u·η·M(s)``; the frame receives the
    opposite torque through the stator (the reduction's housing is part of the frame).
    """

    kind = "motor"

    def __init__(
        self,
        data: MotorData,
        ratio: float,
        efficiency: float = 1.0,
        body: str = "crank",
        enabled: bool = True,
        name: str | None = None,
    ):
        super().__init__(name)
        self.data = data
        self.ratio = float(ratio)
        self.efficiency = float(efficiency)
        self.body = body
        self.enabled = enabled
        self.acts_on = (body,)

    @classmethod
    def for_crank_speed(cls, data: MotorData, crank_speed: float, **kw) -> Motor:
        """Reduction chosen so that the body turns at ``crank_speed`` at the rated slip."""
        u = data.omega_sync * (1.0 - data.rated_slip) / crank_speed
        return cls(data, u, **kw)

    def bind(self, mechanism) -> None:
        mechanism.body(self.body)  # raises KeyError for an unknown body
        self._constants()  # kept from the start: the same attributes at every call

    def _constants(self):
        """(ω_sync, M_k, s_k) of ``data``, computed once per data (the same formulas)."""
        d = self.data
        if self.__dict__.get("_data_of") is not d:
            self._k = (d.omega_sync, d.breakdown_torque, d.breakdown_slip)
            self._data_of = d
        return self._k

    def torque(self, body_rate: float) -> float:
        if not self.enabled:
            return 0.0
        w_sync, mk, sk = self._constants()
        s = 1.0 - self.ratio * body_rate / w_sync
        # MotorData.torque with its constants kept
        return self.ratio * self.efficiency * (2.0 * mk * s * sk / (s * s + sk * sk))

    def loads(self, t, kin) -> Loads:
        m = self.torque(kin.rate(self.body))
        return Loads(torques=[(self.body, m)], frame=[("frame", -m)])

    def generalized_force(self, t, kin) -> list:
        """Q = M·ω*_body: the virtual work of :meth:`loads`."""
        m = self.torque(kin.rate(self.body))
        return [m * w for w in kin.omega(self.body)]

    def power(self, t, kin) -> float:
        rate = kin.rate(self.body)
        return float(self.torque(rate) * rate)
