"""Names used everywhere (CSV columns, units): defined once here.

W is the work done on the moving links by the non-conservative effects (motor, cylinders,
technological load, friction, dampers) since the start; E_impact the kinetic energy lost in
impacts. The energy balance: T + V − (T0 + V0) = W − E_impact.
"""

#: columns of a trajectory, in CSV order, with their units
COLUMNS = {
    "t": "s",
    "phi": "rad",
    "psi": "rad",
    "phi_dot": "rad/s",
    "psi_dot": "rad/s",
    "phi_ddot": "rad/s^2",
    "psi_ddot": "rad/s^2",
    "x_C": "m",
    "T": "J",
    "V": "J",
    "W": "J",
    "E_impact": "J",
    "structure": "",
    "chart": "",
}

NUMERIC_COLUMNS = tuple(k for k, u in COLUMNS.items() if k not in ("structure", "chart"))
