"""MuJoCo as a peer: the free press as a MuJoCo model, stepped by MuJoCo's RK4 from Python.

What a user would write instead of mps: two kinematic trees, crank–rod (hinges at O and A) and
slider–rocker (a slide along the guide at C, a hinge at C), closed at B by an equality
``connect``; the scene's masses, inertias and centres of mass; gravity; the motor's torque on the
crank from a control callback (``mjcb_control``), which MuJoCo calls at every RK4 stage. The
model is written in the scene's initial configuration (a ``connect`` holds where the model is
defined), so its joint coordinates are offsets from the initial angles and position.

**Its settings**: ``integrator="RK4"``, the step ``dt``; contacts off; the closure is a soft
constraint with ``solref = (2·dt, 1)`` (the stiffest MuJoCo allows without turning its safety
off: a time constant of two steps, critically damped) and ``solimp = (0.9999, 0.9999, 0.001)``
(the most impedance: on ``paper`` at dt = 2 ms, 2.3e-4 rad off against 7.2e-3 with (0.99,
0.999); a time constant of one step, safety off, does worse); the solver's defaults otherwise.
A soft constraint has an error of its own: the closure |B_rod − B_rocker| is reported
(``closure``), and the run's φ against an exact reference says what it costs.

The ``bench`` extra installs the ``mujoco`` wheel; :func:`available` says whether it is there.
Only what the exact peer covers is modelled (:func:`mps_core.bench.peers.supports`: the free
mechanism with gravity and the motor).
"""

from __future__ import annotations

import math
import time

import numpy as np

from .peers import PeerRun, exact_model, supports

__all__ = ["available", "press_xml", "run_mujoco", "bare_loop"]


def available() -> tuple[bool, str]:
    try:
        import mujoco  # noqa: F401
    except ImportError:
        return False, "mujoco is not installed (pip install -e '.[bench]')"
    return True, ""


def press_xml(scene, dt: float) -> str:
    """The MJCF of a scene's free press, in its initial configuration (press frame: x up the
    guide, y across, z out of the plane; hinges about z)."""
    ok, why = supports(scene)
    if not ok:
        raise ValueError(f"scene {scene.name!r}: the MuJoCo peer does not cover {why}")
    model = exact_model(scene)
    p = model.params
    phi, psi, xc = (float(v) for v in model.initial_state()[:3])
    ax, ay = p.l1 * math.cos(phi), p.l1 * math.sin(phi)
    bx, by = xc + p.l3 * math.cos(psi), p.l3 * math.sin(psi)
    rod = math.atan2(by - ay, bx - ax)
    bodies = {b[0]: b for b in p.bodies}

    def inertial(name):
        _n, m, j, _o, _t, a, b, _len = bodies[name]
        # a planar hinge turns about z alone; the other two axes only satisfy MuJoCo's
        # triangle inequality (a body that does not turn, the slider, gets a token inertia)
        j = max(float(j), 1e-9)
        return (
            f'<inertial pos="{float(a)!r} {float(b)!r} 0" mass="{float(m)!r}" '
            f'diaginertia="{j / 2!r} {j / 2!r} {j!r}"/>'
        )

    def quat(angle):
        return f"{math.cos(angle / 2)!r} 0 0 {math.sin(angle / 2)!r}"

    return f"""<mujoco model="press">
  <option timestep="{dt!r}" integrator="RK4" gravity="{p.g[0]!r} {p.g[1]!r} 0">
    <flag contact="disable"/>
  </option>
  <worldbody>
    <body name="crank" pos="0 0 0" quat="{quat(phi)}">
      <joint name="crank" type="hinge" axis="0 0 1"/>
      {inertial("crank")}
      <body name="rod" pos="{p.l1!r} 0 0" quat="{quat(rod - phi)}">
        <joint name="rod" type="hinge" axis="0 0 1"/>
        {inertial("rod")}
      </body>
    </body>
    <body name="slider" pos="{xc!r} 0 0">
      <joint name="slider" type="slide" axis="1 0 0"/>
      {inertial("slider")}
      <body name="rocker" pos="0 0 0" quat="{quat(psi)}">
        <joint name="rocker" type="hinge" axis="0 0 1"/>
        {inertial("rocker")}
      </body>
    </body>
  </worldbody>
  <equality>
    <connect body1="rod" body2="rocker" anchor="{p.l2!r} 0 0"
             solref="{2 * dt!r} 1" solimp="0.9999 0.9999 0.001"/>
  </equality>
  <actuator>
    <motor name="motor" joint="crank" gear="1" ctrllimited="false"/>
  </actuator>
</mujoco>"""


def _model(scene, dt: float):
    """The compiled model, its data in the scene's initial state, the crank's indices and the
    control callback (the motor's torque from the crank's rate) with its call count."""
    import mujoco

    model = exact_model(scene)
    phi0, psi0, xc0, phid0, psid0, xcd0 = (float(v) for v in model.initial_state())
    m = mujoco.MjModel.from_xml_string(press_xml(scene, dt))
    d = mujoco.MjData(m)
    p = model.params
    ax, ay = p.l1 * math.cos(phi0), p.l1 * math.sin(phi0)
    bx, by = xc0 + p.l3 * math.cos(psi0), p.l3 * math.sin(psi0)
    # the rod's rate from the closure: B's velocity from both sides
    vax, vay = -ay * phid0, ax * phid0
    vbx, vby = xcd0 - p.l3 * math.sin(psi0) * psid0, p.l3 * math.cos(psi0) * psid0
    rx, ry = bx - ax, by - ay
    rod_rate = (rx * (vby - vay) - ry * (vbx - vax)) / (rx * rx + ry * ry)
    jc, jr, js, jk = (m.joint(n).dofadr[0] for n in ("crank", "rod", "slider", "rocker"))
    qc = m.joint("crank").qposadr[0]
    d.qvel[jc], d.qvel[jr], d.qvel[js], d.qvel[jk] = phid0, rod_rate - phid0, xcd0, psid0
    motor = model.motor
    calls = [0]

    def control(m_, d_):
        calls[0] += 1
        d_.ctrl[0] = motor.torque(d_.qvel[jc]) if motor is not None else 0.0

    return m, d, qc, jc, phi0, control, calls


def run_mujoco(scene, t_end: float, t_eval, dt: float) -> PeerRun:
    """Step the scene's free press with MuJoCo's RK4 at ``dt`` to ``t_end``; φ, φ̇, φ̈ at
    ``t_eval`` (each a whole number of steps from 0). The CPU counts the stepping, the control
    callback and the reading of the outputs, not the model's compilation.

    The loop is what a MuJoCo user who wants the accelerations at the outputs writes: ``mj_step``
    with the RK4 integrator is ``mj_forward`` (the state's accelerations: RK4's first stage)
    then ``mj_RungeKutta``; here each step is ``mj_RungeKutta`` then ``mj_forward`` at the new
    state, whose accelerations are both what the output reports and the next step's first
    stage. So the outputs cost no forward pass more than a bare ``mj_step`` loop (one in all,
    the first state's): four a step, the torque callback at each (``nfev`` counts its calls).
    :func:`bare_loop` is that bare loop, for the bench to print the ratio."""
    import mujoco

    m, d, qc, jc, phi0, control, calls = _model(scene, dt)
    t_eval = np.asarray(t_eval, float)
    steps = np.rint(t_eval / dt).astype(int)
    if np.any(np.abs(steps * dt - t_eval) > 1e-9 * max(1.0, float(t_end))):
        raise ValueError(f"dt = {dt!r}: the outputs are not whole numbers of steps")
    phi, phid, phidd = (np.empty(t_eval.size) for _ in range(3))
    closure = 0.0
    rk, forward = mujoco.mj_RungeKutta, mujoco.mj_forward
    qpos, qvel, qacc = d.qpos, d.qvel, d.qacc  # views of the data, made once
    hypot = math.hypot
    mujoco.set_mjcb_control(control)
    try:
        c0 = time.process_time()
        forward(m, d)  # the first state's accelerations
        k = 0
        for i, s in enumerate(steps.tolist()):
            while k < s:
                rk(m, d, 4)
                forward(m, d)
                k += 1
            phi[i] = phi0 + qpos[qc]
            phid[i] = qvel[jc]
            phidd[i] = qacc[jc]
            if d.nefc:  # the connect's three rows: B's gap
                e = d.efc_pos
                gap = hypot(e[0], e[1], e[2])
                if gap > closure:
                    closure = gap
        cpu = time.process_time() - c0
    finally:
        mujoco.set_mjcb_control(None)
    return PeerRun(t_eval, phi, phid, phidd, cpu, calls[0], closure)


def bare_loop(scene, t_end: float, dt: float) -> tuple[float, int]:
    """The plainest MuJoCo loop of the same model: ``mj_step`` to ``t_end``, the crank's angle
    and rate read after each step, the same torque callback at every stage; (its CPU s, the
    callback's calls)."""
    import mujoco

    m, d, qc, jc, phi0, control, calls = _model(scene, dt)
    n = int(round(t_end / dt))
    step = mujoco.mj_step
    qpos, qvel = d.qpos, d.qvel
    mujoco.set_mjcb_control(control)
    try:
        c0 = time.process_time()
        for _ in range(n):
            step(m, d)
            phi0 + qpos[qc], qvel[jc]
        cpu = time.process_time() - c0
    finally:
        mujoco.set_mjcb_control(None)
    return cpu, calls[0]
