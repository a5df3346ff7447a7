"""The errors that mps_core raises. Each names what failed, where and when."""

from __future__ import annotations

import math


def _fmt_config(config: dict | None) -> str:
    if not config:
        return ""
    parts = []
    for k, v in config.items():
        if isinstance(v, float):
            if k.endswith("_deg"):
                parts.append(f"{k}={v:.6g}")
            else:
                parts.append(f"{k}={v:.9g}")
        else:
            parts.append(f"{k}={v}")
    return " (" + ", ".join(parts) + ")"


class MpsError(Exception):
    """Base of every error mps_core raises on purpose."""


class SceneError(MpsError, ValueError):
    """A scene is malformed: names the field, the value found and what was expected."""

    def __init__(self, field: str, value: object, expected: str, source: str | None = None):
        self.field = field
        self.value = value
        self.expected = expected
        self.source = source
        where = f"{source}: " if source else ""
        super().__init__(f"{where}{field} = {value!r}: expected {expected}")


class ChartDomainError(MpsError):
    """A position function was evaluated outside its chart (no real closed-form solution).

    Internal signal between the engine and the driver, which answers it by changing chart or by
    raising :class:`ChartBreakdown` / :class:`SingularConfiguration`.
    """

    def __init__(self, chart: str, detail: str):
        self.chart = chart
        self.detail = detail
        super().__init__(f"chart {chart}: {detail}")


class SimulationError(MpsError):
    """A run cannot go on; carries the simulated time and the configuration there."""

    def __init__(self, message: str, t: float, config: dict | None = None):
        self.t = t
        self.config = dict(config or {})
        super().__init__(f"t = {t:.9g} s: {message}{_fmt_config(self.config)}")


class ChartBreakdown(SimulationError):
    """The current chart degenerates and chart switching is turned off."""


class SingularConfiguration(SimulationError):
    """No chart of the structure is regular here: a true singularity of the machine."""


class NumericalError(SimulationError):
    """The equations produced a non-finite or unusable value (never passed on as NaN)."""


def config_in_degrees(values: dict) -> dict:
    """Angles in degrees for messages: keys named phi/psi/theta get a _deg suffix."""
    out = {}
    for k, v in values.items():
        if k in ("phi", "psi") or k.startswith("theta"):
            out[k + "_deg"] = math.degrees(float(v))
        else:
            out[k] = float(v) if isinstance(v, (int, float)) else v
    return out


class Interrupted(KeyboardInterrupt):
    """A command stopped by a signal (Ctrl-C's SIGINT, or SIGTERM); ``kept``: what it kept, and
    where, said in the command's one line."""

    def __init__(self, signal_name: str = "SIGINT", kept: str = ""):
        self.signal_name = signal_name
        self.kept = kept
        super().__init__(f"interrupted ({signal_name})" + (f": {kept}" if kept else ""))


def signal_name(exc: BaseException) -> str:
    """Return the signal an interruption came from: SIGTERM where it says so, else SIGINT."""
    return getattr(exc, "signal_name", "SIGINT")


def raise_interrupted(signum: int, _frame: object) -> None:
    """Raise :class:`Interrupted` for signal ``signum`` (a handler for SIGTERM)."""
    import signal

    raise Interrupted(signal.Signals(signum).name)
