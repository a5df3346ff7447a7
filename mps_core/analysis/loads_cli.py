"""``mps loads SCENE|RECORDING``: the load report of a steady working cycle.

    mps loads SCENE|RECORDING [--json FILE] [--csv FILE] [--png FILE] [--harmonics N]
                              [--structure NAME] [--t-end S] [--dt S] [--events FILE]

SCENE is a preset name or a scene file: it is run with reactions. RECORDING is a CSV written by
``mps run SCENE --reactions --csv FILE`` (one row a step, the reaction columns included), with
its event log (``--events FILE``, JSON lines from ``mps run --events``) for the transients; or an
MCAP recording (``mps record``, the node), which holds its own event log and scene: it is read by
the reader that a package names for the format ``mcap`` (entry point group ``mps.recordings``),
imported only then (``mps_core`` never imports mcap), with no re-simulation. The report (see
:mod:`mps_core.analysis.loads`) is printed as a table; ``--json``/``--csv`` write it for tools
and ``--png`` draws the figure.
"""

from __future__ import annotations

import json
import sys
from pathlib import Path

from ..dynamics.reaction_csv import read_csv
from ..dynamics.reaction_observer import ReactionObserver
from ..plugins import reader
from . import loads


def register(subparsers) -> None:
    p = subparsers.add_parser(
        "loads", help="load report over a steady working cycle: peaks, RMS, harmonics, impulses"
    )
    p.add_argument(
        "source",
        metavar="SCENE|RECORDING",
        help="preset name, scene file (TOML), a CSV from mps run --reactions --csv, "
        "or an MCAP recording (mps record, the node)",
    )
    p.add_argument("--json", metavar="FILE", help="write the report as JSON (- : standard output)")
    p.add_argument("--csv", metavar="FILE", help="write one row a quantity as CSV (- : standard output)")
    p.add_argument("--png", metavar="FILE", help="draw the figure (time series + harmonics)")
    p.add_argument(
        "--harmonics",
        type=int,
        default=loads.N_HARMONICS,
        metavar="N",
        help=f"harmonics of the crank frequency (default {loads.N_HARMONICS})",
    )
    p.add_argument(
        "--structure",
        default="locked",
        metavar="NAME",
        help="the working structure whose last full revolution is analysed (default locked)",
    )
    p.add_argument("--t-end", type=float, metavar="S", help="end time of the run (s), scenes only")
    p.add_argument("--dt", type=float, metavar="S", help="step of the run (s), scenes only")
    p.add_argument(
        "--events", metavar="FILE", help="a recording's event log (JSON lines) for the transients' impulses"
    )
    p.add_argument(
        "--force",
        action="store_true",
        help="replace an output file that exists (a regular file only; never an input)",
    )
    p.add_argument(
        "-q",
        "--quiet",
        action="store_true",
        help="no progress line while a scene runs (there is one on a terminal only)",
    )
    p.set_defaults(func=run)


from ..files.inputs import MCAP_MAGIC, read_text  # noqa: E402


def is_mcap(src: str) -> bool:
    """An MCAP recording: named .mcap, a file that starts with MCAP's magic, or a bag (a
    directory with a metadata.yaml or .mcap files)."""
    if src.lower().endswith(".mcap"):
        return True
    p = Path(src)
    if p.is_dir():
        return (p / "metadata.yaml").is_file() or any(p.glob("*.mcap"))
    try:
        with p.open("rb") as fh:
            return fh.read(8) == MCAP_MAGIC
    except OSError:
        return False


def _mcap_columns(args):
    src = args.source
    if args.t_end is not None or args.dt is not None:
        raise loads.LoadReportError("--t-end and --dt apply to scenes, not to a recording")
    if args.events is not None:
        raise loads.LoadReportError(
            "--events applies to a CSV recording; an MCAP recording holds its own event log"
        )
    ep = reader("mcap")
    try:
        if ep is None:  # no package installed that reads MCAP
            raise ModuleNotFoundError("no reader of MCAP recordings", name="mcap")
        load_columns = ep.load()
    except ModuleNotFoundError as exc:
        raise loads.LoadReportError(
            f"reading the MCAP recording {src!r} needs the package {exc.name!r}, which is not "
            f"installed: install the viewer extra (pip install -e '.[view]') or convert "
            f"the run to CSV (mps run SCENE --reactions --csv FILE)"
        ) from None
    return load_columns(src)


def _columns(args):
    src = args.source
    if is_mcap(src):
        return _mcap_columns(args)
    if src.lower().endswith(".csv"):
        if args.t_end is not None or args.dt is not None:
            raise loads.LoadReportError("--t-end and --dt apply to scenes, not to a recording")
        read_text(src, "recording", "a CSV file")
        return read_csv(src), _events(args.events), Path(src).name
    if args.events is not None:
        raise loads.LoadReportError("--events applies to a recording; a scene's run keeps its own")
    from ..run.build import build
    from ..scene import load_scene

    scene = load_scene(src).with_overrides(t_end=args.t_end, dt=args.dt)
    sim = build(scene)
    obs = ReactionObserver()
    sim.observers.append(obs)
    from ..run.progress import Progress

    progress = Progress(sim.solver.t, scene.t_end, label=scene.name, quiet=args.quiet)
    try:
        traj = sim.run(scene.t_end, scene.dt, progress=progress)
    finally:
        progress.done()
    return traj.columns, list(traj.events), scene.name


def _events(path) -> list[dict]:
    if path is None:
        return []
    out = []
    text = read_text(path, "--events", "JSON lines", allow_empty=True)  # a run without events
    for i, line in enumerate(text.splitlines(), 1):
        if line.strip():
            try:
                out.append(json.loads(line))
            except json.JSONDecodeError as exc:
                raise loads.LoadReportError(f"--events {path}: line {i} is not JSON ({exc.msg})") from None
    return out


def run(args) -> int:
    import contextlib

    from ..files.outputs import STDOUT, check_outputs

    if not 1 <= args.harmonics <= 50:
        raise loads.LoadReportError(f"--harmonics = {args.harmonics}: expected 1 to 50")
    # before the run or the reading: paths that cannot be written, inputs, existing files
    check_outputs(
        {"--json": args.json, "--csv": args.csv, "--png": args.png},
        inputs=[args.source, args.events],
        force=args.force,
        streams={"--json", "--csv"},
    )
    stdout = sys.stdout
    # standard output carries an output: the table and what the command says go to stderr
    quiet = STDOUT in (args.json, args.csv)
    with contextlib.redirect_stdout(sys.stderr) if quiet else contextlib.nullcontext():
        return _report(args, stdout)


def _report(args, stdout) -> int:
    """Make the report and write its outputs; ``stdout``: where ``-`` writes."""
    from ..files.outputs import written_whole

    columns, events, name = _columns(args)
    report = loads.load_report(columns, n=args.harmonics, mode=args.structure, events=events, source=name)
    print(loads.format_table(report))
    for path, write in (
        (args.json, lambda tmp: loads.write_json(report, tmp)),
        (args.csv, lambda tmp: loads.write_csv(report, tmp)),
        (args.png, lambda tmp: loads.write_png(report, columns, tmp)),
    ):
        if path:
            with written_whole(path, stdout) as tmp:
                write(tmp)
            print(f"wrote {'standard output' if path == '-' else path}")
    return 0
