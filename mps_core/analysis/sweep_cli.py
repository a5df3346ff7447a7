"""``mps sweep``: the load report over a grid, a list or a sample of a scene's fields
(:mod:`.sweep`), on local worker processes or a Dask cluster, resumable."""

from __future__ import annotations

import json
import os
import sys
import time
from pathlib import Path

from . import sweep as sw

#: what a sweep writes into its folder, beside the runs' record (``runs.jsonl``)
OUTPUTS = {"table": "sweep.csv", "envelope": "envelope.csv", "spec": "sweep.json", "figure": "sweep.png"}


def register(subparsers) -> None:
    p = subparsers.add_parser(
        "sweep", help="the load report over many runs of a scene: a table and its envelope"
    )
    p.add_argument("scene", metavar="SCENE", help="preset name or scene file (TOML)")
    p.add_argument(
        "--vary",
        action="append",
        required=True,
        metavar="KEY=SPEC",
        help="a field and its values: a:b:n (grid), v1,v2,... (list) or a:b (a range "
        "for --samples); dotted TOML keys, effects and commands by name, e.g. "
        "effects.blanking.thickness_mm=0.5:2.0:7 (repeat for more fields: the "
        "grid is their product)",
    )
    p.add_argument(
        "--samples", type=int, metavar="N", help="N runs from a Latin hypercube over the ranges a:b"
    )
    p.add_argument("--seed", type=int, default=0, help="the sample's seed (default 0)")
    p.add_argument(
        "--out",
        required=True,
        metavar="DIR",
        help="folder of the results: runs.jsonl (each run as it ends; the same "
        "command again computes only what is missing), sweep.csv, "
        "envelope.csv, sweep.json, sweep.png",
    )
    p.add_argument(
        "--workers",
        type=int,
        metavar="N",
        help=f"local worker processes (default: the machine's cores, {os.cpu_count()})",
    )
    p.add_argument(
        "--scheduler",
        metavar="ADDRESS",
        help="a Dask scheduler (tcp://HOST:PORT) instead of local workers (the batch extra)",
    )
    p.add_argument("--t-end", type=float, metavar="S", help="end time of every run (s)")
    p.add_argument("--dt", type=float, metavar="S", help="output step of every run (s)")
    p.add_argument(
        "--structure",
        default="locked",
        metavar="NAME",
        help="the working structure whose last full revolution is analysed (default locked)",
    )
    p.add_argument(
        "--no-vectorise",
        dest="vectorise",
        action="store_false",
        help="every run on its own (by default the runs whose scenes allow it, ones without "
        "events with a fixed-step solver such as working's, go in vectorised batches: the "
        "same rows, to round-off)",
    )
    p.add_argument(
        "--batch-size",
        type=int,
        default=sw.BATCH_SIZE,
        metavar="N",
        help=f"runs a vectorised batch holds at most (default {sw.BATCH_SIZE})",
    )
    p.add_argument("--force", action="store_true", help="write into a folder that holds another sweep")
    p.add_argument(
        "-q", "--quiet", action="store_true", help="no progress line (there is one on a terminal only)"
    )
    p.set_defaults(func=run)


class _Progress:
    """One line on a terminal: runs done and failed, the rate, the time left."""

    def __init__(self, quiet: bool, stream=None):
        self.stream = stream or sys.stderr
        self.on = not quiet and self.stream.isatty()
        self.t0 = time.monotonic()
        self.failed = 0
        self.first: int | None = None  # rows kept from an earlier call

    def __call__(self, row: dict, done: int, total: int) -> None:
        if row.get("status") != "ok":
            self.failed += 1
        if not self.on:
            return
        if self.first is None:
            self.first = done - 1
        dt = time.monotonic() - self.t0
        rate = (done - self.first) / dt if dt > 0 else 0.0
        left = (total - done) / rate if rate > 0 else float("nan")
        self.stream.write(
            f"\rsweep: {done}/{total} runs, {self.failed} failed, {rate:.2f} runs/s, {left:.0f} s left   "
        )
        self.stream.flush()

    def done(self) -> None:
        if self.on:
            self.stream.write("\r\033[K")
            self.stream.flush()


def _spec(args, scene) -> dict:
    from ..version import __version__

    return {
        "scene": scene.name,
        "scene_origin": scene.origin,
        "scene_text": scene.text,
        "vary": list(args.vary),
        "samples": args.samples,
        "seed": args.seed,
        "t_end": args.t_end,
        "dt": args.dt,
        "structure": args.structure,
        "version": __version__,
    }


def _check_folder(out: Path, spec: dict, force: bool) -> None:
    """A folder that holds another sweep is refused (its table would be replaced); the same
    sweep of another code version is not another sweep (its runs are computed again)."""
    if out.exists() and not out.is_dir():
        raise sw.SweepError(f"--out {str(out)!r}: a file, not a folder")
    if not out.parent.is_dir():
        raise sw.SweepError(f"--out {str(out)!r}: no directory {str(out.parent)!r}")
    old = out / OUTPUTS["spec"]
    if old.is_file() and not force:
        try:
            before = json.loads(old.read_text())
        except (OSError, json.JSONDecodeError):
            before = None
        if before is None or {**before, "version": None} != {**spec, "version": None}:
            raise sw.SweepError(
                f"--out {str(out)!r} holds another sweep ({old.name} differs): "
                "expected a new folder, that sweep's own arguments, or --force"
            )
    if out.is_dir() and not os.access(out, os.W_OK):
        raise sw.SweepError(f"--out {str(out)!r}: not writable")


def _write_outputs(result, out: Path, title: str) -> list:
    """The table, the envelope and, where a run succeeded, the plot, each written whole; the
    envelope."""
    from ..files.outputs import written_whole

    with written_whole(out / OUTPUTS["table"]) as tmp:
        sw.write_csv(result.rows, result.columns(), tmp)
    env = result.envelope()
    with written_whole(out / OUTPUTS["envelope"]) as tmp:
        sw.write_csv(env, ["figure", "value", "run", *result.keys], tmp)
    if any(r.get("status") == "ok" for r in result.rows):
        with written_whole(out / OUTPUTS["figure"]) as tmp:
            sw.write_png(result, tmp, title=title)
    return env


def run(args) -> int:
    from ..files.outputs import written_whole
    from ..scene import load_scene

    scene = load_scene(args.scene)
    out = Path(args.out)
    spec = _spec(args, scene)
    # every run's scene is built and checked before anything runs
    runs = sw.plan(scene, args.vary, samples=args.samples, seed=args.seed, t_end=args.t_end, dt=args.dt)
    _check_folder(out, spec, args.force)
    if args.workers is not None and args.workers < 1:
        raise sw.SweepError(f"--workers {args.workers}: expected an integer >= 1")
    if args.batch_size < 1:
        raise sw.SweepError(f"--batch-size {args.batch_size}: expected an integer >= 1")
    client = _client(args.scheduler)
    out.mkdir(exist_ok=True)
    with written_whole(out / OUTPUTS["spec"]) as tmp:
        Path(tmp).write_text(json.dumps(spec, indent=1) + "\n")
    progress = _Progress(args.quiet)
    print(
        f"sweep {scene.name}: {len(runs)} runs, "
        + (
            f"Dask scheduler {args.scheduler}"
            if client
            else f"{args.workers or os.cpu_count()} worker process(es)"
        )
        + f"; rows in {out}"
    )
    try:
        result = sw.sweep(
            scene,
            args.vary,
            samples=args.samples,
            seed=args.seed,
            t_end=args.t_end,
            dt=args.dt,
            structure=args.structure,
            workers=args.workers,
            client=client,
            out=out,
            on_row=progress,
            vectorise=args.vectorise,
            batch_size=args.batch_size,
            planned=runs,
        )
    except KeyboardInterrupt:
        progress.done()
        kept = len(sw.read_runs(out / sw.RUNS_FILE))
        print(
            f"sweep interrupted: {kept} run(s) kept in {out / sw.RUNS_FILE}; the same "
            "command again computes the rest",
            file=sys.stderr,
        )
        return 130
    finally:
        if client is not None:
            client.close()
    progress.done()
    _summary(result, _write_outputs(result, out, scene.name), out)
    return 0


def _client(scheduler: str | None):
    """A client of the Dask scheduler at ``scheduler`` (None: no cluster)."""
    if not scheduler:
        return None
    try:
        from dask.distributed import Client
    except ModuleNotFoundError:
        raise sw.SweepError(
            "--scheduler needs dask.distributed: install the batch extra (pip install -e '.[batch]')"
        ) from None
    return Client(scheduler)


def _summary(result, env: list, out: Path) -> None:
    """What the sweep did, its foundation load's envelope, its failures, the files written."""
    failed = [r for r in result.rows if r.get("status") != "ok"]
    print(
        f"{len(result.rows)} runs ({result.computed} computed now, "
        f"{len(result.rows) - result.computed} kept from before), {len(failed)} failed"
    )
    if result.vectorised:
        print(f"  {result.vectorised} of the runs computed now in vectorised batches")
    for e in env:
        if e["figure"] in ("|F_found|.peak", "|F_found|.rms", "|F_found|.A1", "|F_found|.A2"):
            at = ", ".join(f"{k}={e[k]!r}" for k in result.keys)
            print(f"  envelope {e['figure']}: {e['value']:.1f} N at run {e['run']} ({at})")
    for r in failed[:5]:
        print(f"  run {r['run']} failed: {r['error']}")
    print(
        "wrote "
        + ", ".join(str(out / OUTPUTS[k]) for k in ("table", "envelope", "spec"))
        + ("" if not (out / OUTPUTS["figure"]).exists() else f", {out / OUTPUTS['figure']}")
    )
