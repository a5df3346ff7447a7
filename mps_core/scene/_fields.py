"""Reading a scene file's tables field by field: the checks of a value (a number, a positive
one, one of some choices, a step, a tolerance), each raising :class:`~mps_core.errors.SceneError`
with the field, the value and what was expected, and :class:`Table`, which refuses the keys no
parser asked for (with a hint where a key lacks its unit)."""

from __future__ import annotations

import math

from ..errors import SceneError
from ..solvers import ADAPTIVE_SOLVERS, FIXED_STEP_SOLVERS


def num(fieldname, v, expected="a number") -> float:
    if isinstance(v, bool) or not isinstance(v, (int, float)) or not math.isfinite(v):
        raise SceneError(fieldname, v, expected)
    return float(v)


def positive(fieldname, v, upper=None, unit="") -> float:
    x = num(fieldname, v, f"a positive number{unit}")
    if x <= 0 or (upper is not None and x > upper):
        rng = f" up to {upper:g}" if upper is not None else ""
        raise SceneError(fieldname, v, f"a positive number{unit}{rng}")
    return x


def choice(fieldname, v, options):
    if v not in options:
        raise SceneError(fieldname, v, "one of " + ", ".join(repr(o) for o in options))
    return v


def displacement(fieldname, deg) -> float:
    x = num(fieldname, deg, "a virtual displacement in degrees")
    if not (1e-7 <= x <= 5.0):
        raise SceneError(fieldname, deg, "a virtual displacement between 1e-7° and 5°")
    return math.radians(x)


def tolerance(fieldname, v) -> float:
    x = num(fieldname, v, "a tolerance")
    if not (1e-15 <= x <= 1e-2):
        raise SceneError(fieldname, v, "a tolerance between 1e-15 and 1e-2")
    return x


def fixed_step(fieldname, step, t_end) -> float:
    """A fixed-step solver's own step (seconds): as a step of the output grid."""
    check_dt(fieldname, step, t_end)
    return float(step)


def check_step_solver(st) -> None:
    if st.name in ADAPTIVE_SOLVERS:
        raise SceneError(
            "solver.step_s",
            st.step,
            "no step for the adaptive solver " + st.name + " (it chooses its own): "
            f"a fixed-step solver ({', '.join(FIXED_STEP_SOLVERS)})",
        )


def check_dt(fieldname, dt, t_end):
    x = num(fieldname, dt, "a step in seconds")
    if not (1e-8 <= x <= 0.1):
        raise SceneError(fieldname, dt, "a step between 1e-8 s and 0.1 s")
    if x > t_end:
        raise SceneError(fieldname, dt, f"a step no longer than t_end_s = {t_end:g}")
    if t_end / x > 5e7:
        raise SceneError(fieldname, dt, f"at most 5e7 steps over t_end_s = {t_end:g}")


def nonneg(fieldname, v, unit) -> float:
    x = num(fieldname, v, f"a number >= 0{unit}")
    if x < 0:
        raise SceneError(fieldname, v, f"a number >= 0{unit}")
    return x


class Table:
    """Reads one TOML table, remembering which keys were used so leftovers are refused."""

    def __init__(self, data, path: str, units_hint: dict | None = None):
        if not isinstance(data, dict):
            raise SceneError(path, data, "a table")
        self.data = data
        self.path = path
        self.used: set[str] = set()
        self.units_hint = units_hint or {}

    def get(self, key, default=None, required=False):
        self.used.add(key)
        if key not in self.data:
            if required:
                near = [k for k, v in self.units_hint.items() if v == key and k in self.data]
                if near:
                    raise SceneError(
                        f"{self.path}.{near[0]}",
                        self.data[near[0]],
                        f"no such key (did you mean {key!r}? units go in the key's name)",
                    )
                raise SceneError(f"{self.path}.{key}", None, "a value (this field is required)")
            return default
        return self.data[key]

    def field(self, key):
        return f"{self.path}.{key}"

    def done(self):
        for k in self.data:
            if k not in self.used:
                hint = self.units_hint.get(k)
                exp = (
                    f"no such key (did you mean {hint!r}? units go in the key's name)"
                    if hint
                    else "no such key; known keys: " + ", ".join(sorted(self.used))
                )
                raise SceneError(f"{self.path}.{k}", self.data[k], exp)


#: keys without their unit, by table, and the key meant (a refused key's hint)
UNIT_HINTS = {
    "mechanism": {"l1": "l1_mm", "l2": "l2_mm", "l3": "l3_mm"},
    "initial": {"phi": "phi_deg", "psi": "psi_deg", "phi_dot": "phi_dot_rad_s", "psi_dot": "psi_dot_rad_s"},
    "solver": {"t_end": "t_end_s", "dt": "dt_s", "delta": "delta_deg"},
    "body": {
        "mass": "mass_kg",
        "inertia": "inertia_kg_m2",
        "com": "com_mm",
        "J": "inertia_kg_m2",
        "m": "mass_kg",
    },
    "structure": {"psi_lock": "psi_lock_deg"},
}
