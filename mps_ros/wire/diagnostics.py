"""The node's ``/diagnostics``: its statuses as the diagnostics aggregator reads them
(``diagnostic_msgs/msg/DiagnosticArray`` as message dicts), each named ``NODE: what``, its
``hardware_id`` the scene's press (``mps SCENE``), its level about the last window (the
time since the status before: a status clears once its trouble is over), its figures as
key/values.

- ``pacing``: OK; WARN where deadlines were missed in the window; ERROR where more than half
  of the window's steps missed theirs (the node cannot keep up); STALE while the node is
  paused (its lifecycle's inactive state: simulated time holds).
- ``commands``: accepted, refused (of which as floods), lost on the way; WARN where a flood was
  refused or commands were lost in the window.
- ``recording``: the file, its bytes on disk so far, the messages handed to it; ERROR once it
  has stopped (the disk full), why, and the messages dropped since.
"""

from __future__ import annotations

from typing import Any

OK, WARN, ERROR, STALE = 0, 1, 2, 3


def hardware_id(scene_name: str) -> str:
    """The statuses' ``hardware_id``: the twin of the scene's press."""
    return f"mps {scene_name}"


def _value(v) -> str:
    return f"{v:.6g}" if isinstance(v, float) else str(v)


def status(level: int, name: str, message: str, hardware: str, values: dict) -> dict:
    return {
        "level": level,
        "name": name,
        "message": message,
        "hardware_id": hardware,
        "values": [{"key": k, "value": _value(v)} for k, v in values.items()],
    }


def tracking(tracked: Any, name: str, hardware: str) -> dict:
    """Return the ``NAME: tracking`` status of a tracker's ``tracked`` one (OK, WARN, ERROR; since when)."""
    level = {"OK": OK, "WARN": WARN, "ERROR": ERROR}[tracked.level]
    values = {"level": tracked.level, "since_s": float(tracked.since)}
    return status(level, name, tracked.line(), hardware, values)


def array(t_ns: int, statuses: list) -> dict:
    """The DiagnosticArray of ``statuses``, stamped with the simulated time ``t_ns``."""
    return {
        "header": {"stamp": {"sec": t_ns // 1_000_000_000, "nanosec": t_ns % 1_000_000_000}, "frame_id": ""},
        "status": statuses,
    }


class Window:
    """Counters' growth since the last look: ``since(misses=..., steps=...)`` gives each
    counter's rise since the call before (from 0 at the first) and keeps the new values."""

    def __init__(self):
        self._last: dict[str, int] = {}

    def since(self, **counts: int) -> dict[str, int]:
        out = {k: v - self._last.get(k, 0) for k, v in counts.items()}
        self._last.update(counts)
        return out


def pacing(name: str, hardware: str, stats: dict, misses: int, steps: int, realtime: bool) -> dict:
    """The pacing status from the run's ``stats`` (:meth:`~mps_ros.run.runner.Runner.stats`), with
    ``misses`` deadlines missed in the window's ``steps``."""
    level = OK
    if realtime and misses:
        level = ERROR if 2 * misses > steps else WARN
    msg = (
        f"rtf {stats['real_time_factor']:.3g}, step p50 {stats['step_time_p50_ms']:.3g} ms "
        f"p99 {stats['step_time_p99_ms']:.3g} ms, {misses} deadline misses since the last "
        f"report, {stats['deadline_misses']} in all"
    )
    if level == ERROR:
        msg = f"cannot keep up: {misses} of {steps} steps late since the last report; " + msg
    return status(level, f"{name}: pacing", msg, hardware, stats)


def paused(name: str, hardware: str, t: float) -> dict:
    """The pacing status while the run is paused at simulated time ``t``: STALE."""
    return status(
        STALE,
        f"{name}: pacing",
        f"paused at t = {t:.6f} s (the node is inactive)",
        hardware,
        {"paused_at_s": t},
    )


def commands(
    name: str,
    hardware: str,
    accepted: int,
    refused: int,
    floods: int,
    lost: int,
    new_floods: int,
    new_lost: int,
) -> dict:
    """The commands status: the run's counts so far; WARN where ``new_floods`` were refused as
    a flood or ``new_lost`` lost on the way in the window."""
    msg = f"{accepted} accepted, {refused} refused ({floods} as floods), {lost} lost on the way"
    trouble = []
    if new_floods:
        trouble.append(f"{new_floods} refused as a flood")
    if new_lost:
        trouble.append(f"{new_lost} lost on the way")
    if trouble:
        msg = " and ".join(trouble) + " since the last report; " + msg
    return status(
        WARN if trouble else OK,
        f"{name}: commands",
        msg,
        hardware,
        {
            "commands_accepted": accepted,
            "commands_refused": refused,
            "commands_refused_as_floods": floods,
            "commands_lost": lost,
        },
    )


def recording(
    name: str,
    hardware: str,
    path,
    size: int,
    messages: int,
    failure: str | None = None,
    dropped: int = 0,
    files: int = 1,
) -> dict:
    """The recording status: OK while it records (``size``: its ``files``' bytes on disk so
    far, ``messages`` handed to it); ERROR once it has stopped (``failure``: why; ``dropped``:
    the messages not recorded since)."""
    values = {"path": str(path), "files": files, "bytes": size, "messages": messages, "dropped": dropped}
    if failure:
        return status(
            ERROR,
            f"{name}: recording",
            f"recording stopped: {failure}",
            hardware,
            {**values, "error": failure},
        )
    return status(
        OK,
        f"{name}: recording",
        f"recording to {path}: {size / 1e6:.3g} MB, {messages} messages",
        hardware,
        values,
    )


__all__ = [
    "OK",
    "WARN",
    "ERROR",
    "STALE",
    "hardware_id",
    "status",
    "array",
    "Window",
    "pacing",
    "paused",
    "commands",
    "recording",
]
