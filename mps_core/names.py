"""Names used everywhere (CSV columns, units): defined once here."""

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
    "structure": "",
    "chart": "",
}

NUMERIC_COLUMNS = tuple(k for k, u in COLUMNS.items() if k not in ("structure", "chart"))
