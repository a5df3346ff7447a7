"""Scene files: presets load, bad input is refused with a message naming field, value, expectation."""

import math

import pytest

from mps_core import SceneError, load_scene, preset_names, scene_from_text

PAPER_TEXT = load_scene("paper").text


def test_paper_preset_is_the_seeds_test():
    s = load_scene("paper")
    assert "paper" in preset_names()
    assert (s.geometry.l1, s.geometry.l2, s.geometry.l3) == (0.015, 0.040, 0.030)
    assert s.structure == "free" and s.assembly == 1
    assert math.degrees(s.initial["phi"]) == pytest.approx(-64.1)
    assert math.degrees(s.initial["psi"]) == pytest.approx(-46.34)
    assert s.initial["phi_dot"] == 43.5 and s.initial["psi_dot"] == 0.0
    assert s.t_end == 0.05 and s.steps == 40
    assert s.solver.name == "linear-acceleration" and s.solver.scheme == "central"
    assert math.degrees(s.solver.delta) == pytest.approx(0.1)
    assert [e.kind for e in s.effects] == ["gravity", "motor"]
    assert {k: (b.mass, b.inertia) for k, b in s.bodies.items()} == {
        "crank": (4.6, 0.034),
        "rod": (20.0, 0.036),
        "rocker": (18.0, 0.0441),
        "slider": (100.0, 0.0),
    }


def test_motor_preset_numbers():
    s = load_scene("paper")
    motor = s.build_effects(s.mechanism())[1]
    d = motor.data
    assert d.rated_torque == pytest.approx(1500 / (50 * math.pi * 0.942))
    assert d.breakdown_slip == pytest.approx(0.058 * (2.2 + math.sqrt(2.2**2 - 1)))
    assert motor.ratio == pytest.approx(50 * math.pi * 0.942 / 43.5)
    # rated torque at the rated speed, through the reduction
    assert motor.torque(43.5) == pytest.approx(motor.ratio * d.rated_torque, rel=1e-12)
    assert motor.torque(d.omega_sync / motor.ratio) == 0.0


def edit(old, new):
    assert old in PAPER_TEXT, old
    return PAPER_TEXT.replace(old, new, 1)


BAD = [
    (edit("l2_mm = 40.0", "l2_mm = -40.0"), "mechanism.l2_mm", "positive"),
    (edit("l2_mm = 40.0", "l2_mm = 10.0"), "mechanism.l2_mm", "longer than the crank"),
    (edit("l1_mm = 15.0", "l1 = 15.0"), "mechanism.l1", "l1_mm"),
    (edit("l1_mm = 15.0", 'l1_mm = "15"'), "mechanism.l1_mm", "positive number"),
    (edit("assembly = 1 ", "assembly = 2 "), "mechanism.assembly", "one of 1, -1"),
    (edit('type = "press"', 'type = "lathe"'), "mechanism.type", "'press'"),
    (edit("mass_kg = 4.6", "mass_kg = -4.6"), "bodies.crank.mass_kg", "positive"),
    (edit("inertia_kg_m2 = 0.034", "inertia_kg_m2 = -1.0"), "bodies.crank.inertia_kg_m2", ">= 0"),
    (edit("com_mm = [15.0, 0.0]", "com_mm = [15.0]"), "bodies.crank.com_mm", "two numbers"),
    (edit("[bodies.crank]", "[bodies.crank]\ncolour = 'red'"), "bodies.crank.colour", "no such key"),
    (edit('initial = "free"', 'initial = "floating"'), "structure.initial", "'free'"),
    (edit("phi_deg = -64.1", "phi = -64.1"), "initial.phi", "phi_deg"),
    (
        edit("psi_deg = -46.34", "psi_deg = 120.0").replace("l3_mm = 30.0", "l3_mm = 90.0"),
        "initial",
        "assemble",
    ),
    (edit('type = "gravity"', 'type = "magnetism"'), "effects[0].type", "one of"),
    (edit("g_m_s2 = [-9.81, 0.0]", "g_m_s2 = -9.81"), "effects[0].g_m_s2", "two numbers"),
    (edit('model = "4A80B4U3"', 'model = "4A90"'), "effects[1].model", "motor preset"),
    (edit("efficiency = 1.0", "efficiency = 1.5"), "effects[1].efficiency", "(0, 1]"),
    (edit('method = "linear-acceleration"', 'method = "euler"'), "solver.method", "one of"),
    (edit('derivatives = "central"', 'derivatives = "forward"'), "solver.derivatives", "one of"),
    (edit("delta_deg = 0.1", "delta_deg = 30.0"), "solver.delta_deg", "between"),
    (edit("delta_deg = 0.1", "delta_deg = 0.0"), "solver.delta_deg", "between"),
    (edit("t_end_s = 0.05", "t_end_s = -1.0"), "solver.t_end_s", "positive"),
    (edit("steps = 40", "steps = 40\ndt_s = 0.001"), "solver.steps", "not both"),
    (edit("steps = 40", "dt_s = 1.0"), "solver.dt_s", "between"),
    (edit("steps = 40", "steps = 0"), "solver.steps", "positive integer"),
    (
        edit("corrector_iterations = 1", "corrector_iterations = 1.5"),
        "solver.corrector_iterations",
        "integer",
    ),
    (edit("switch_below = 0.5", "switch_below = 1e-5"), "charts.switch_below", "between"),
    (edit("switching = true", 'switching = "yes"'), "charts.switching", "true or false"),
    (PAPER_TEXT + "\n[extras]\nx = 1\n", "section", "one of the sections scene, mechanism, bodies"),
    ("this is = = not toml", "scene file", "valid TOML"),
    (PAPER_TEXT + '\n[[effects]]\ntype = "gravity"\n', "effects", "each effect once"),
]

IDLE_TEXT = load_scene("idle").text
PC_TEXT = load_scene("press-cycle").text


def edit_idle(old, new, text=None):
    text = text or IDLE_TEXT
    assert old in text, old
    return text.replace(old, new, 1)


BAD += [
    (
        PAPER_TEXT + '\n[[effects]]\ntype = "springs"\nstiffness_n_m = 1e4\npreload_n = 10.0\n',
        "mechanism.x_top_mm",
        "needs it",
    ),
    (edit_idle("x_top_mm = 25.5", "x_top_mm = 90.0"), "mechanism.x_top_mm", "can reach"),
    (edit_idle("stiffness_n_m = 20000.0", "stiffness_n_m = -5.0"), "effects[2].stiffness_n_m", "positive"),
    (edit_idle("preload_n = 2500.0", ""), "effects[2].preload_n", "required"),
    (edit_idle('model = "rigid"', 'model = "rubber"'), "effects[3].model", "one of"),
    (edit_idle('model = "rigid"', 'model = "elastic"'), "effects[3].stiffness_n_m", "contact stiffness"),
    (
        edit_idle('[[effects]]\ntype = "top_stop"\nmodel = "rigid"', ""),
        "structure.initial",
        "top_stop effect for the held",
    ),
    (edit_idle("psi_deg = -46.34", "psi_deg = -120.0"), "initial.psi_deg", "near the closure"),
    (edit_idle('command = "engage"', 'command = "jump"', PC_TEXT), "commands[0].command", "one of"),
    (edit_idle("t_s = 0.4351", "t_s = 7.0", PC_TEXT), "commands[1].t_s", "within t_end_s"),
    (edit_idle("t_s = 0.008", "t = 0.008", PC_TEXT), "commands[0].t", "t_s"),
    (edit_idle('[[effects]]\ntype = "latch"\n', "", PC_TEXT), "commands[0].command", "missing: latch"),
    (edit_idle("thickness_mm = 1.0", "thickness_mm = 0.0", PC_TEXT), "effects[7].thickness_mm", "positive"),
    (edit_idle("stroke_mm = 1.5", "stroke_mm = 40.0", PC_TEXT), "effects[4].stroke_mm", "up to 10"),
    (edit_idle("[solver]", '[solver]\nstiff = "ignore"', PC_TEXT), "solver.stiff", "one of"),
    (
        edit_idle("[solver]", "[outputs]\nreactions = 1\n\n[solver]", PC_TEXT),
        "outputs.reactions",
        "true or false",
    ),
]


@pytest.mark.parametrize("text,field,expected", BAD, ids=[b[1] + ":" + b[2] for b in BAD])
def test_bad_scene_is_refused_with_a_clear_message(text, field, expected):
    with pytest.raises(SceneError) as info:
        scene_from_text(text)
    msg = str(info.value)
    assert msg.startswith(field) or f"{field} =" in msg, msg
    assert expected in msg, msg


@pytest.mark.parametrize(
    "header,misspelt,meant",
    [
        ("[initial]", "inital", "initial"),
        ("[solver]", "sovler", "solver"),
        ("[[effects]]", "effect", "effects"),
    ],
)
def test_a_misspelt_section_is_named_before_what_it_leaves_missing(header, misspelt, meant):
    text = PC_TEXT.replace(header, header.replace(meant, misspelt))
    assert text != PC_TEXT
    with pytest.raises(SceneError) as info:
        scene_from_text(text)
    err = info.value
    assert (err.field, err.value) == ("section", misspelt), str(err)
    assert f"(did you mean [{meant}]?)" in str(err)
    assert "scene, mechanism, bodies, structure, initial, commands, effects, solver, outputs, charts" in str(
        err
    )


def test_an_unknown_section_far_from_any_is_named_without_a_guess():
    with pytest.raises(SceneError) as info:
        scene_from_text(PC_TEXT + "\n[zzz]\nx = 1\n")
    assert str(info.value).startswith("section = 'zzz': expected one of the sections scene, ")
    assert "did you mean" not in str(info.value)


def test_messages_are_all_different():
    msgs = set()
    for text, _, _ in BAD:
        with pytest.raises(SceneError) as info:
            scene_from_text(text)
        msgs.add(str(info.value))
    assert len(msgs) == len(BAD)


def test_unknown_preset_or_path():
    with pytest.raises(SceneError, match="a preset name"):
        load_scene("no-such-scene")


def test_overrides_are_validated():
    s = load_scene("paper")
    assert s.with_overrides(t_end=0.1, dt=1e-4).steps == 1000
    assert s.with_overrides(t_end=0.1).dt == s.dt  # a new end time keeps the step
    with pytest.raises(SceneError, match="solver.dt_s"):
        s.with_overrides(dt=-1.0)
    with pytest.raises(SceneError, match="solver.method"):
        s.with_overrides(solver="euler")


def test_a_table_read_before_gives_its_own_parse_again():
    """The tables' parses are kept by their text (scene.tables._TABLES): a scene built again from the
    same tables equals the first; 1, 1.0 and true stay apart; a refused table is refused
    again; a scene's dicts are its own."""
    import tomllib

    from mps_core.scene import scene_from_dict

    raw = tomllib.loads(PAPER_TEXT)
    a, b = scene_from_dict(raw), scene_from_dict(raw)
    assert a == b and a.bodies is not b.bodies and a.initial is not b.initial
    a.bodies["slider"] = None
    assert scene_from_dict(raw).bodies == b.bodies
    raw.setdefault("outputs", {})["reactions"] = True
    assert scene_from_dict(raw).reactions is True
    for bad in (1, 1.0, "true"):
        raw["outputs"]["reactions"] = bad
        for _ in range(2):
            with pytest.raises(SceneError, match="outputs.reactions"):
                scene_from_dict(raw)
    raw["outputs"]["reactions"] = False
    raw["bodies"]["slider"]["mass_kg"] = 90
    assert scene_from_dict(raw).bodies["slider"].mass == 90 and not scene_from_dict(raw).reactions
