"""The reaction columns: what :mod:`.reactions` gives at a state and a trajectory's CSV carries
beside the motion, in order, with their units and meanings (contract §7, then the residuals);
the joints' own among them (:data:`JOINT_COLUMNS`)."""

from __future__ import annotations

from ..model.press import PRESS_JOINTS

#: reaction columns of a trajectory, in CSV order, with their units (contract §7, then residuals)
REACTION_COLUMNS: dict[str, str] = {
    "F_O_x": "N",
    "F_O_y": "N",
    "F_A_x": "N",
    "F_A_y": "N",
    "F_B_x": "N",
    "F_B_y": "N",
    "F_C_x": "N",
    "F_C_y": "N",
    "N_guide": "N",
    "M_guide": "N*m",
    "M_latch": "N*m",
    "F_stop": "N",
    "M_motor": "N*m",
    "F_found_x": "N",
    "F_found_y": "N",
    "M_found_O": "N*m",
    "residual_force_N": "N",
    "residual_moment_Nm": "N*m",
    "balance_residual_N": "N",
    "balance_residual_Nm": "N*m",
}

#: what each reaction column is: receiving body, point, axes
DESCRIPTIONS: dict[str, str] = {
    **{
        c: f"{j.meaning}, {axis}"
        for j in PRESS_JOINTS
        for c, axis in zip(
            j.columns,
            [
                {
                    "x": "x component (frame axes: x along the guide, up)",
                    "y": "y component (frame axes: y across the guide)",
                    "m": "about z, counter-clockwise positive",
                }[k]
                for k in j.components
            ],
        )
    },
    "M_motor": "torque the crank receives from the motor (the frame receives -M_motor through "
    "the stator), about z",
    "F_found_x": "foundation load: x component of the resultant force the frame receives from "
    "the moving links and the effects (along the guide, up)",
    "F_found_y": "foundation load: y component of the resultant force the frame receives (across the guide)",
    "M_found_O": "foundation load: resultant moment about O the frame receives, about z",
    "residual_force_N": "norm of the force rows left over by the least-squares solve "
    "(the equation of motion's residual)",
    "residual_moment_Nm": "norm of the moment rows left over by the least-squares solve",
    "balance_residual_N": "|sum m a_G - (effect forces on moving links - forces the frame "
    "receives from them)|",
    "balance_residual_Nm": "the same balance for moments about O",
}

#: the joints' columns: the unknowns a structure may solve for (no motor, foundation or check)
JOINT_COLUMNS = tuple(
    c
    for c in REACTION_COLUMNS
    if c
    not in (
        "M_motor",
        "F_found_x",
        "F_found_y",
        "M_found_O",
        "residual_force_N",
        "residual_moment_Nm",
        "balance_residual_N",
        "balance_residual_Nm",
    )
)
