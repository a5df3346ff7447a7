"""The design envelope: one scene run over a grid, a list or a sample of its fields' values,
each run through the load report (:mod:`.loads`), one row a run, and the envelope over the runs.

A sweep names the fields it varies by their dotted TOML keys. An effect is named by its type
(``effects.blanking.thickness_mm``), a command by its word (``commands.engage.t_s``), an entry of
an array also by its index (``effects.3.force_n``); every other key is the path through the
scene file's tables (``bodies.slider.mass_kg``, ``solver.dt_s``). Values:

* ``a:b:n``, n values from a to b (a grid axis; ``n = 1`` gives a);
* ``v1,v2,...``, a list (numbers, ``true``/``false`` or words, e.g. ``solver.method=rk4,rk8``);
* ``a:b``, a range to sample (``samples=N``: a Latin hypercube of N runs over the ranges).

Every run's scene is built and validated before any run starts: a key the scene does not have, a
value of the wrong type or one the scene refuses fails the sweep at once, naming the key.

Each run is keyed by its scene's content (the varied file, as JSON, with the code version): its
row is appended to ``runs.jsonl`` as soon as it is done, so that a sweep started again with the
same arguments after Ctrl-C or a lost worker computes only the runs still missing. A run that
fails (a scene that cannot be simulated, no steady cycle) is a row with its error.

Runs whose scenes can share a vectorised pass (:mod:`mps_core.run.batch`: scenes without events
or commands, e.g. ``locked`` ones of ``working``, with a fixed-step solver, alike but for masses,
initial state and effect parameters) go
in batches, each batch a task: its rows, the same as the runs' one by one to round-off, are
recorded together as it ends. ``vectorise=False`` runs every run on its own.

The table is a list of rows (dicts); :meth:`Sweep.records` gives a numpy record array (numpy
only: the core depends on nothing heavier, and a record array reads into pandas with
``pandas.DataFrame.from_records`` where one wants it).
"""

from __future__ import annotations

import contextlib
import functools
import hashlib
import itertools
import json
import math
import os
import time
from collections.abc import Callable, Iterable, Sequence
from concurrent.futures import FIRST_COMPLETED, ProcessPoolExecutor, wait
from concurrent.futures.process import BrokenProcessPool
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np

from ..errors import MpsError, SceneError
from ..scene import Scene, load_scene, scene_from_dict
from ..version import __version__
from . import loads

#: what a row holds of each quantity of the load report, beside its harmonics' amplitudes
FIGURES = loads.FIGURES
#: the rows' file, one JSON object a line, appended as the runs end (the resumable record)
RUNS_FILE = "runs.jsonl"


class SweepError(MpsError, ValueError):
    """A sweep's specification cannot be run (a key, a value, a range)."""


# -- the specification ----------------------------------------------------------------------
@dataclass(frozen=True)
class Axis:
    """One varied field: its dotted key and its values (grid/list), or a range to sample."""

    key: str
    values: tuple = ()
    low: float | None = None
    high: float | None = None

    @property
    def sampled(self) -> bool:
        return self.low is not None


def _word(text: str) -> Any:
    """A list entry: a number (int where it is one), true/false, else the word itself."""
    t = text.strip()
    if t.lower() in ("true", "false"):
        return t.lower() == "true"
    try:
        return int(t)
    except ValueError:
        pass
    try:
        return float(t)
    except ValueError:
        return t


def _number(key: str, spec: str, text: str) -> float:
    try:
        v = float(text)
    except ValueError:
        raise SweepError(
            f"--vary {key}={spec}: {text!r} is not a number (expected a:b:n, a:b or v1,v2,...)"
        ) from None
    if not math.isfinite(v):
        raise SweepError(f"--vary {key}={spec}: {text!r}: expected a finite number")
    return v


def parse_axis(text: str) -> Axis:
    """``KEY=SPEC`` (see the module's notes) as an :class:`Axis`."""
    key, eq, spec = text.partition("=")
    key, spec = key.strip(), spec.strip()
    if not eq or not key or not spec:
        raise SweepError(f"--vary {text!r}: expected KEY=SPEC, e.g. effects.blanking.thickness_mm=0.5:2.0:7")
    if ":" in spec:
        parts = spec.split(":")
        if len(parts) == 2:
            lo, hi = (_number(key, spec, p) for p in parts)
            if not lo < hi:
                raise SweepError(f"--vary {key}={spec}: expected a range low:high with low < high")
            return Axis(key, low=lo, high=hi)
        if len(parts) != 3:
            raise SweepError(f"--vary {key}={spec}: expected a:b:n, a:b or v1,v2,...")
        lo, hi = (_number(key, spec, p) for p in parts[:2])
        try:
            n = int(parts[2])
        except ValueError:
            n = 0
        if n < 1:
            raise SweepError(f"--vary {key}={spec}: the count {parts[2]!r}: expected an integer >= 1")
        vals = [lo] if n == 1 else list(np.linspace(lo, hi, n))
        if (
            float(lo).is_integer()
            and float(hi).is_integer()
            and all(float(v).is_integer() for v in vals)
            and all(p.strip().lstrip("+-").isdigit() for p in parts[:2])
        ):
            return Axis(key, tuple(int(round(v)) for v in vals))
        return Axis(key, tuple(float(v) for v in vals))
    return Axis(key, tuple(_word(p) for p in spec.split(",")))


def _points(axes: Sequence[Axis], samples: int | None, seed: int) -> list[tuple]:
    """The runs' values, one tuple a run in the axes' order."""
    if samples is None:
        bad = [a.key for a in axes if a.sampled]
        if bad:
            raise SweepError(
                f"--vary {bad[0]}: a range low:high is sampled: give --samples N (or a:b:n for a grid)"
            )
        return list(itertools.product(*(a.values for a in axes)))
    if samples < 1:
        raise SweepError(f"--samples {samples}: expected an integer >= 1")
    bad = [a.key for a in axes if not a.sampled]
    if bad:
        raise SweepError(f"--vary {bad[0]}: --samples draws from ranges low:high only")
    from scipy.stats import qmc

    unit = qmc.LatinHypercube(d=len(axes), seed=seed).random(samples)
    lo = np.array([a.low for a in axes])
    hi = np.array([a.high for a in axes])
    return [tuple(float(v) for v in row) for row in lo + unit * (hi - lo)]


def _entry(seq: list, key: str, head: str, by: str) -> dict:
    """The table of an array (``effects``, ``commands``) that ``head`` names: its index, or
    the one whose ``by`` field is ``head``."""
    if head.isdigit():
        i = int(head)
        if i >= len(seq):
            raise SweepError(f"--vary {key}: the scene has {len(seq)} entries there")
        return seq[i]
    found = [e for e in seq if isinstance(e, dict) and e.get(by) == head]
    if not found:
        have = ", ".join(str(e.get(by)) for e in seq if isinstance(e, dict)) or "none"
        raise SweepError(f"--vary {key}: the scene has no {by} {head!r} (it has: {have})")
    if len(found) > 1:
        raise SweepError(
            f"--vary {key}: the scene has {len(found)} of {by} {head!r}: name one by its index instead"
        )
    return found[0]


def set_field(raw: dict, key: str, value: Any) -> None:
    """Set the dotted ``key`` in a parsed scene file (see the module's notes)."""
    parts = key.split(".")
    if len(parts) < 2 or not all(parts):
        raise SweepError(f"--vary {key}: expected a dotted key TABLE.FIELD, e.g. bodies.slider.mass_kg")
    if parts[0] in ("effects", "commands"):
        if len(parts) != 3:
            raise SweepError(f"--vary {key}: expected {parts[0]}.NAME.FIELD")
        by = "type" if parts[0] == "effects" else "command"
        table = _entry(raw.get(parts[0], []), key, parts[1], by)
        if parts[2] == by:
            raise SweepError(f"--vary {key}: the {by} names the entry; it is not varied")
        table[parts[2]] = value
        return
    table = raw
    for p in parts[:-1]:
        nxt = table.setdefault(p, {})
        if not isinstance(nxt, dict):
            raise SweepError(f"--vary {key}: {p!r} is not a table in the scene")
        table = nxt
    table[parts[-1]] = value


@dataclass(frozen=True)
class Run:
    """One run of a sweep: its index, the values it varies, its scene and its key."""

    index: int
    values: dict
    scene: Scene
    key: str


def _base_raw(scene: Scene) -> dict:
    import tomllib

    if not scene.text:
        raise SweepError(f"scene {scene.name!r} has no file text to vary (load it from a preset or a file)")
    return tomllib.loads(scene.text)


def plan(
    scene: Scene | str,
    vary: Iterable[str | Axis],
    *,
    samples: int | None = None,
    seed: int = 0,
    t_end: float | None = None,
    dt: float | None = None,
) -> list[Run]:
    """Every run of a sweep, each scene built and validated (nothing is run)."""
    base = scene if isinstance(scene, Scene) else load_scene(scene)
    axes = [a if isinstance(a, Axis) else parse_axis(a) for a in vary]
    if not axes:
        raise SweepError("a sweep varies at least one field: give --vary KEY=SPEC")
    keys = [a.key for a in axes]
    if len(set(keys)) != len(keys):
        raise SweepError(f"--vary: a key is given twice ({', '.join(keys)})")
    raw0 = _base_raw(base)
    solver = raw0.setdefault("solver", {})
    if t_end is not None:
        solver["t_end_s"] = float(t_end)
    if dt is not None:
        solver.pop("steps", None)
        solver["dt_s"] = float(dt)
    raw0.setdefault("outputs", {})["reactions"] = True
    # the file's text as JSON, its tables in order: those no key varies written once
    varied = {k.split(".")[0] for k in keys}
    fixed = {t: f"{json.dumps(t)}: {_json(v)}" for t, v in raw0.items() if t not in varied}
    runs = []
    for i, point in enumerate(_points(axes, samples, seed)):
        # the base's own parse, changed in place: each run sets every varied key before its
        # scene is built and its key taken (and a scene is built without changing its file)
        raw = raw0
        values = dict(zip(keys, point))
        for k, v in values.items():
            set_field(raw, k, v)
        try:
            sc = scene_from_dict(raw, name=base.name, origin=base.origin)
        except SceneError as exc:
            shown = ", ".join(f"{k}={v!r}" for k, v in values.items())
            raise SweepError(f"run {i} ({shown}): {exc}") from None
        text = ", ".join(fixed.get(t) or f"{json.dumps(t)}: {_json(raw[t])}" for t in sorted(raw))
        runs.append(Run(i, values, sc, run_key("{" + text + "}")))
    return runs


def _json(data) -> str:
    """A scene file's part as :func:`run_key` reads it."""
    return json.dumps(data, sort_keys=True, default=str)


def run_key(text: str) -> str:
    """A run's key: of the code's version and its scene file as JSON (its tables and their
    keys in order: :func:`_json` of the whole file)."""
    return hashlib.sha256(f"{__version__}\n{text}".encode()).hexdigest()[:16]


# -- one run --------------------------------------------------------------------------------
def figures(report: dict) -> dict:
    """A load report as one row's figures: each quantity's mean, peak, RMS, dynamic RMS and
    harmonic amplitudes (``|F_found|.peak``, ``|F_found|.A1``…), the cycle's period and mean
    crank speed, and the impacts' count and largest foundation impulse."""
    quantities = [
        (q["name"], [q[f] for f in FIGURES], [h["amplitude"] for h in q["harmonics"]])
        for q in report["quantities"]
    ]
    return _row(report["cycle"]["period_s"], quantities, report["transients"])


def _row(period: float, quantities, transients) -> dict:
    """A row's figures: ``quantities`` (name, the :data:`FIGURES`, the amplitudes A_1…A_n)."""
    row: dict = {"period_s": period, "crank_speed_rad_s": loads.TWO_PI / period}
    for name, values, amplitudes in quantities:
        row.update(zip(_columns(name, len(amplitudes)), itertools.chain(values, amplitudes)))
    found = [
        math.hypot(
            ev.get("impulses_Ns", {}).get("F_found_x", 0.0), ev.get("impulses_Ns", {}).get("F_found_y", 0.0)
        )
        for ev in transients
    ]
    row["impacts"] = len(found)
    row["impulse_found_max_Ns"] = max(found) if found else 0.0
    return row


@functools.cache
def _columns(name: str, harmonics: int) -> tuple[str, ...]:
    """A quantity's columns: its :data:`FIGURES`, then its amplitudes A_1…A_n (made once: the
    rows of a sweep share them, in memory and in what the workers send back)."""
    return tuple(f"{name}.{f}" for f in FIGURES) + tuple(f"{name}.A{k}" for k in range(1, harmonics + 1))


def run_one(scene: Scene, structure: str = "locked") -> tuple[dict, float]:
    """The figures of one run (or its error: any exception of the run or its report), and the
    CPU seconds the simulation took."""
    from ..run.build import build

    c0 = time.process_time()
    try:
        traj = build(scene).run(scene.t_end, scene.dt)
        cpu = time.process_time() - c0
        report = loads.load_report(traj.columns, mode=structure, events=traj.events, source=scene.name)
        return {"status": "ok", "error": "", **figures(report)}, cpu
    except Exception as exc:  # a run that cannot be simulated is a row, not the end
        return {"status": "failed", "error": f"{type(exc).__name__}: {exc}"}, time.process_time() - c0


#: what a task gives for each run: its row, the CPU seconds of its simulation and of all of
#: it, and whether it ran in a vectorised batch
Result = tuple[dict, float, float, bool]


def _task(scene: Scene, structure: str) -> Result:
    c0 = time.process_time()
    row, sim_cpu = run_one(scene, structure)
    return row, sim_cpu, time.process_time() - c0, False


def run_batch(scenes: Sequence[Scene], structure: str = "locked") -> list[Result]:
    """The rows of scenes that share one vectorised pass (:mod:`mps_core.run.batch`), their
    load reports made together (:mod:`.batch_loads`), each with its share of the CPU seconds
    (the simulation's, and all of it); where they cannot share it after all, each run on its
    own (:func:`run_one`)."""
    from ..run.batch import run_states
    from .batch_loads import RunFigures, batch_figures

    c0 = time.process_time()
    try:
        states = run_states(scenes)
        sim_cpu = (time.process_time() - c0) / len(scenes)
        c1 = time.process_time()
        results = batch_figures(states, structure)
    except Exception:  # NotVectorisable, or anything the pass met: the runs one by one
        return [_task(sc, structure) for sc in scenes]
    report_cpu = (time.process_time() - c1) / len(scenes)
    out = []
    for res in results:
        if isinstance(res, RunFigures):
            quantities = [
                (name, v[: len(FIGURES)], v[len(FIGURES) :])
                for name, v in zip(res.names, res.values.tolist())
            ]
            row = {"status": "ok", "error": "", **_row(res.period, quantities, ())}
        else:  # as run_one: a run without a report is a row with its error
            row = {"status": "failed", "error": f"{type(res).__name__}: {res}"}
        out.append((row, sim_cpu, sim_cpu + report_cpu, True))
    return out


def _work(scenes: list[Scene], structure: str, batch: bool) -> list[Result]:
    """One task of a sweep: a vectorised batch, or one run (a list of one scene)."""
    return run_batch(scenes, structure) if batch else [_task(sc, structure) for sc in scenes]


#: scene-steps a vectorised batch of a sweep holds at most: each step's state, and the blocks of
#: its load reports; about 50 B each at the batch's peak (working, 1000 to 3400 runs of 1751
#: steps: 0.20 to 0.42 GB resident, the process's own included; docs/loads.md)
BATCH_STATES = 6_000_000

#: runs a vectorised batch of a sweep holds at most, unless told: a batch's step costs numpy's
#: calls more than their arithmetic at a thousand runs (working with exact derivatives: a run
#: 8 and 10 % cheaper in batches of 2000 than of 1000 in ``mps bench sweep --vectorised``'s two
#: runs of docs/loads.md; on two workers, 4000 runs in batches of 2000 quicker than of 1000 or
#: 1400 in a temporary script; none clearly cheaper in 3000 or 3400)
BATCH_SIZE = 2000


#: the fewest runs a vectorised batch takes, by derivative scheme (fewer go one by one): with
#: central differences a batch of 5 runs costs 1.1 to 1.4 times its runs one by one, and a
#: batch of 10 0.6 to 0.8 times (``mps bench sweep --vectorised``, docs/loads.md)
MIN_BATCH = {"central": 10, "autodiff": 2}


def tasks(
    todo: Sequence[Run],
    workers: int,
    vectorise: bool = True,
    batch_size: int = BATCH_SIZE,
    min_batch: int | None = None,
) -> list:
    """The sweep's runs as tasks ``(batch, runs)``: the runs whose scenes can share a
    vectorised pass (:func:`mps_core.run.batch.group_key`; at least :data:`MIN_BATCH` of them)
    in batches of at most ``batch_size`` runs and :data:`BATCH_STATES` scene-steps, split so
    that each of the ``workers`` gets one where they are enough, the batches of a group as
    even as they can be and, where there are more than the workers, as many as a multiple of
    them (the workers' last batches end together); every other run a task of its own.
    ``min_batch``: the fewest runs of a batch instead of :data:`MIN_BATCH`'s."""
    from ..run.batch import group_key

    width = max(1, workers)
    groups: dict = {}
    for r in todo:
        groups.setdefault(group_key(r.scene) if vectorise else None, []).append(r)
    out: list = []
    for key, runs in groups.items():
        least = MIN_BATCH.get(runs[0].scene.solver.scheme, 2) if min_batch is None else min_batch
        if key is None or len(runs) < least:
            out.extend((False, [r]) for r in runs)
            continue
        sc = runs[0].scene
        steps = max(1, int(round(sc.t_end / sc.dt))) + 1
        share = max(least, -(-len(runs) // width))
        size = min(batch_size, max(1, BATCH_STATES // steps), share)
        count = -(-len(runs) // size)  # as many batches, as even as they can be
        even = -(-count // width) * width  # a multiple of the workers: none ends alone
        if count > width and len(runs) // even >= least:
            count = even
        ends = [len(runs) * i // count for i in range(count + 1)]
        out.extend((True, runs[a:b]) for a, b in zip(ends, ends[1:]))
    return out


# -- the sweep ------------------------------------------------------------------------------
@dataclass
class Sweep:
    """A sweep's rows (in the runs' order), what it varied, and what this call computed."""

    keys: list
    rows: list
    computed: int = 0
    #: of the runs computed, those that ran in vectorised batches
    vectorised: int = 0
    cpu_s: float = 0.0
    simulation_cpu_s: float = 0.0

    def columns(self) -> list[str]:
        cols = dict.fromkeys(["run", "key", *self.keys, "status", "error"])
        for r in self.rows:  # each column where a row first has it
            cols.update(dict.fromkeys(r))
        return list(cols)

    def records(self) -> np.recarray:
        """The table as a numpy record array (NaN where a failed run has no figure)."""
        cols = self.columns()
        data = []
        for c in cols:
            vals = [r.get(c) for r in self.rows]
            if all(isinstance(v, (int, float)) and not isinstance(v, bool) or v is None for v in vals):
                data.append(np.array([math.nan if v is None else v for v in vals], float))
            else:
                data.append(np.array(["" if v is None else str(v) for v in vals]))
        names = [c.replace("|", "").replace(".", "_") for c in cols]
        return np.rec.fromarrays(data, dtype=np.dtype([(n, a.dtype) for n, a in zip(names, data)]))

    def envelope(self) -> list[dict]:
        """For each figure, its value of largest magnitude over the runs that ended (a mean
        that is negative, e.g. the weight in ``F_found_x.mean``, by its size), and the run
        reaching it."""
        out = []
        ok = [r for r in self.rows if r.get("status") == "ok"]
        for c in self.columns():
            if c in ("run", "key", "status", "error") or c in self.keys:
                continue
            values = [r.get(c) for r in ok]
            best = None
            if values and all(type(v) is float for v in values):  # a figure of every run
                size = np.abs(np.array(values))
                size[~np.isfinite(size)] = -1.0
                k = int(np.argmax(size))  # the first of the largest, as below
                if size[k] >= 0.0:
                    best = (values[k], ok[k])
            else:
                for v, r in zip(values, ok):
                    if (
                        isinstance(v, (int, float))
                        and math.isfinite(v)
                        and (best is None or abs(v) > abs(best[0]))
                    ):
                        best = (v, r)
            if best is not None:
                out.append(
                    {
                        "figure": c,
                        "value": best[0],
                        "run": best[1]["run"],
                        **{k: best[1][k] for k in self.keys},
                    }
                )
        return out


def read_runs(path: Path) -> dict:
    """The rows of earlier calls by run key (a torn last line, from a kill, is left out)."""
    done: dict = {}
    if not path.is_file():
        return done
    for line in path.read_text().splitlines():
        try:
            row = json.loads(line)
        except json.JSONDecodeError:
            continue
        if isinstance(row, dict) and "key" in row:
            done[row["key"]] = row
    return done


def _end_torn_line(path: Path) -> None:
    """A record cut mid-line (a kill while a row was written) is ended there, so that the
    rows appended after it stay lines of their own."""
    if path.is_file() and path.stat().st_size:
        with path.open("rb+") as fh:
            fh.seek(-1, os.SEEK_END)
            if fh.read(1) != b"\n":
                fh.write(b"\n")


def sweep(
    scene: Scene | str,
    vary: Iterable[str | Axis],
    *,
    samples: int | None = None,
    seed: int = 0,
    t_end: float | None = None,
    dt: float | None = None,
    structure: str = "locked",
    workers: int | None = None,
    client: Any = None,
    out: str | Path | None = None,
    on_row: Callable[[dict, int, int], None] | None = None,
    vectorise: bool = True,
    batch_size: int = BATCH_SIZE,
    min_batch: int | None = None,
    planned: list[Run] | None = None,
) -> Sweep:
    """Run a sweep (see the module's notes) and return its table.

    ``workers``: local processes (default: the machine's cores; 1 runs here, in this
    process); ``client``: a ``dask.distributed.Client`` instead. ``out``: a folder whose
    ``runs.jsonl`` keeps every row as it comes (runs already there are not computed again).
    ``on_row(row, done, total)`` is called in this process after each row. ``vectorise``:
    the runs whose scenes can share a vectorised pass (scenes without events with a
    fixed-step solver, :mod:`mps_core.run.batch`) go in batches of up to ``batch_size`` and at
    least ``min_batch`` runs (by default :data:`MIN_BATCH`'s by derivative scheme), their rows
    the same, to round-off; False: every run on its own. ``planned``: what :func:`plan` gave
    for these arguments, where the caller has it (it is not made again)."""
    vary = list(vary)
    runs = (
        planned if planned is not None else plan(scene, vary, samples=samples, seed=seed, t_end=t_end, dt=dt)
    )
    keys = list(runs[0].values)
    record = Path(out) / RUNS_FILE if out is not None else None
    done = read_runs(record) if record is not None else {}
    if record is not None:
        record.parent.mkdir(parents=True, exist_ok=True)
        _end_torn_line(record)
    rows: dict[int, dict] = {}
    todo = []
    for r in runs:
        if r.key in done:
            rows[r.index] = {**done[r.key], "run": r.index}
        else:
            todo.append(r)
    result = Sweep(keys, [])

    def take(task_runs: list[Run], results: list[Result]) -> None:
        """A task's rows: all of them recorded first, then each told (a Ctrl-C in ``on_row``
        loses none of a batch's rows)."""
        made = []
        for r, (row, sim_cpu, cpu, batched) in zip(task_runs, results):
            full = {"run": r.index, "key": r.key, **r.values, **row}
            rows[r.index] = full
            made.append(full)
            result.computed += 1
            result.vectorised += batched
            result.cpu_s += cpu
            result.simulation_cpu_s += sim_cpu
        if record is not None:
            with record.open("a") as fh:
                fh.write("".join(json.dumps(full, default=_json_default) + "\n" for full in made))
        if on_row is not None:
            for i, full in enumerate(made):
                on_row(full, len(rows) - len(made) + i + 1, len(runs))

    n = workers if workers is not None else (os.cpu_count() or 1)
    if batch_size < 1:
        raise SweepError(f"batch_size {batch_size}: expected an integer >= 1")
    if min_batch is not None and min_batch < 1:
        raise SweepError(f"min_batch {min_batch}: expected an integer >= 1 (or None)")
    if client is not None:
        _on_cluster(client, todo, n, (vectorise, batch_size, min_batch), structure, take)
    elif n <= 1 or len(todo) <= 1:
        for batch, task_runs in tasks(todo, 1, vectorise, batch_size, min_batch):
            take(task_runs, _work([r.scene for r in task_runs], structure, batch))
    else:
        _in_processes(tasks(todo, n, vectorise, batch_size, min_batch), n, structure, take)
    result.rows = [rows[i] for i in sorted(rows)]
    return result


def _on_cluster(client, todo: list, n: int, batching: tuple, structure: str, take) -> None:
    """The runs to do as tasks of a Dask cluster (``client``), as many as its workers (``n``
    where it does not say), each task's rows taken as it completes."""
    try:
        width = len(client.scheduler_info().get("workers", {})) or n
    except Exception:  # a client that does not say: as many as local workers
        width = n
    work = tasks(todo, width, *batching)
    futures = {
        client.submit(_work, [r.scene for r in runs], structure, batch, pure=False): runs
        for batch, runs in work
    }
    from dask.distributed import as_completed

    for fut in as_completed(list(futures)):
        take(futures[fut], fut.result())


def _in_processes(todo: list, n: int, structure: str, take: Callable) -> None:
    """The tasks (:func:`tasks`) on ``n`` local worker processes, each task's rows taken as
    they come. A worker that dies (killed, out of memory) breaks its pool: the tasks not yet
    returned go to a new one. Three breaks with no row between them end the sweep (the rows
    taken are kept). The workers leave Ctrl-C to this process: the tasks not started are
    dropped, those under way end and are kept."""
    left, breaks = list(todo), 0
    while left:
        pool = ProcessPoolExecutor(max_workers=min(n, len(left)), initializer=_ignore_sigint)
        pending = {
            pool.submit(_work, [r.scene for r in runs], structure, batch): (batch, runs)
            for batch, runs in left
        }
        broken = False
        try:
            while pending:
                finished, _ = wait(pending, return_when=FIRST_COMPLETED)
                for fut in finished:
                    if isinstance(fut.exception(), BrokenProcessPool):
                        continue
                    take(pending.pop(fut)[1], fut.result())
                    breaks = 0
                if any(isinstance(f.exception(), BrokenProcessPool) for f in finished):
                    broken = True
                    break
        except KeyboardInterrupt:
            for fut in [f for f in pending if not f.cancel()]:
                if fut.exception() is None:
                    take(pending.pop(fut)[1], fut.result())
            raise
        finally:
            if broken:
                _end_workers(pool)
            pool.shutdown(wait=True, cancel_futures=True)
        for fut in [f for f in pending if f.done() and f.exception() is None]:
            take(pending.pop(fut)[1], fut.result())  # ended as the pool broke
        left = list(pending.values())
        if left:
            breaks += 1
            if breaks >= 3:
                raise SweepError(
                    f"the worker processes died three times with no run ending "
                    f"between ({sum(len(runs) for _, runs in left)} run(s) left; the rows "
                    "taken are kept)"
                )


def _end_workers(pool: ProcessPoolExecutor) -> None:
    """Kill a broken pool's worker processes that are left.

    A worker killed while it hands back a result can leave the result queue's lock held, and
    the others then wait on that lock for ever; Python before 3.12 does not end them when the
    pool breaks, and the pool's shutdown would wait for them. Their tasks go to a new pool."""
    for proc in list((getattr(pool, "_processes", None) or {}).values()):
        with contextlib.suppress(OSError, ValueError):
            proc.kill()


def _ignore_sigint() -> None:
    import signal

    signal.signal(signal.SIGINT, signal.SIG_IGN)


def _json_default(o):
    if isinstance(o, np.generic):
        return o.item()
    raise TypeError(f"{type(o).__name__} is not JSON")


# -- outputs --------------------------------------------------------------------------------
def write_csv(rows: list[dict], columns: list[str], path: str | Path) -> Path:
    import csv

    path = Path(path)
    with path.open("w", newline="") as fh:
        w = csv.writer(fh)
        w.writerow(columns)
        w.writerows([v if (v := r.get(c)) is not None else "" for c in columns] for r in rows)
    return path


def write_png(result: Sweep, path: str | Path, title: str = "") -> Path:
    """Peak and RMS of the foundation load against each varied field; the harmonics'
    envelope (the largest amplitude of each over the runs)."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    ok = [r for r in result.rows if r.get("status") == "ok"]
    numeric = [
        k
        for k in result.keys
        if all(isinstance(r[k], (int, float)) and not isinstance(r[k], bool) for r in ok)
    ]
    n = len(numeric) + 1
    fig, axes = plt.subplots(1, n, figsize=(4.2 * n, 3.6), squeeze=False)
    for ax, k in zip(axes[0], numeric):
        x = [r[k] for r in ok]
        for fig_name, style in (("|F_found|.peak", "o"), ("|F_found|.rms", "s")):
            ax.plot(
                x,
                [r.get(fig_name, math.nan) / 1e3 for r in ok],
                style,
                ms=4,
                label=fig_name.replace("|F_found|.", ""),
            )
        ax.set_xlabel(k)
        ax.set_ylabel("foundation load |F_found| (kN)")
        ax.legend(fontsize=8)
        ax.grid(alpha=0.3)
    ax = axes[0][-1]
    amps = sorted({int(c.rsplit(".A", 1)[1]) for r in ok for c in r if c.startswith("|F_found|.A")})
    env = [max(r.get(f"|F_found|.A{k}", 0.0) for r in ok) / 1e3 for k in amps] if ok else []
    ax.bar(amps, env)
    ax.set_xlabel("harmonic of the crank frequency")
    ax.set_ylabel("largest amplitude over the runs (kN)")
    ax.grid(alpha=0.3, axis="y")
    failed = len(result.rows) - len(ok)
    fig.suptitle(
        (title + ": " if title else "") + f"{len(ok)} runs" + (f", {failed} failed" if failed else "")
    )
    fig.tight_layout()
    path = Path(path)
    fig.savefig(path, dpi=110, format="png")
    plt.close(fig)
    return path
