"""``mps view RECORDING.mcap [--save FILE.rrd] [--no-spawn] [--scene SCENE]``: a recording in
the Rerun viewer (:mod:`mps_ros.view.offline`); ``mps view --live [--save FILE.rrd | --connect URL]``:
the running node, followed (:mod:`mps_ros.view.live`).

Without ``--save`` the .rrd goes to a temporary folder and the viewer opens on it; with
``--no-spawn`` it is only written. A viewer started here listens on 127.0.0.1 only.
``--scene`` gives the geometry for a recording that holds no scene metadata. ``--web`` serves
Rerun's web viewer on 127.0.0.1 instead (:mod:`mps_ros.view.web`) and prints its address, for a
machine without a display; it serves until Ctrl-C.
"""

from __future__ import annotations


def register(subparsers) -> None:
    p = subparsers.add_parser("view", help="show a recording (MCAP) in the Rerun viewer, or save it as .rrd")
    p.add_argument(
        "recording",
        metavar="RECORDING.mcap",
        nargs="?",
        help="a recording from mps record or the node, a file or a bag directory (not with --live)",
    )
    p.add_argument(
        "--live",
        action="store_true",
        help="follow the running node instead: its topics streamed to the viewer "
        "(or --save FILE.rrd, or --connect URL) at the display rate",
    )
    p.add_argument(
        "--connect",
        metavar="URL",
        help="--live: stream to a running viewer (rerun+http://127.0.0.1:9876/proxy)",
    )
    p.add_argument("--node", default="press_twin", help="--live: the node's name")
    p.add_argument(
        "--duration",
        type=float,
        metavar="S",
        help="--live: stop after S wall seconds (default: at the run's end)",
    )
    p.add_argument("--hz", type=float, default=30.0, help="--live: frames a wall second (default 30)")
    p.add_argument("--save", metavar="FILE.rrd", help="write the Rerun recording to FILE.rrd")
    p.add_argument(
        "--no-spawn", action="store_true", help="do not open the viewer (with --save: only write the file)"
    )
    p.add_argument(
        "--scene",
        metavar="SCENE",
        help="preset name or scene file for the geometry, if the recording has none",
    )
    p.add_argument(
        "--force", action="store_true", help="replace FILE.rrd where it exists (never the recording)"
    )
    p.add_argument(
        "--web",
        action="store_true",
        help="serve Rerun's web viewer on 127.0.0.1 and print its address (no display needed); until Ctrl-C",
    )
    p.add_argument(
        "--web-port",
        type=int,
        default=9090,
        help="--web: the web viewer's port (default 9090; 0: a free one)",
    )
    p.set_defaults(func=run)


def run(args) -> int:
    from mps_core.files.outputs import check_outputs
    from mps_core.scene import load_scene

    if args.web and not (0 <= args.web_port <= 65535):
        import sys

        port = args.web_port
        print(
            f"mps view: error: --web-port {port}: expected a port from 0 (a free one) to 65535",
            file=sys.stderr,
        )
        return 2

    if args.live:
        if args.recording:
            raise SystemExit("mps view: --live follows the running node: give no recording")
        from ..ros.environment import env_defaults
        from ..view.live import run_live

        env_defaults()  # before rclpy starts: loopback-only discovery unless set

        # before anything starts: never over an existing file without --force, never into a
        # folder that is not there
        check_outputs({"--save": args.save}, force=args.force)
        if args.web and (args.save or args.connect):
            raise SystemExit("mps view: --web streams to the web viewer: give neither --save nor --connect")
        web = _web(None, args.web_port) if args.web else None

        st = run_live(
            scene=load_scene(args.scene or "press-cycle"),
            node_name=args.node,
            save=args.save,
            connect=web.grpc if web is not None else args.connect,
            duration=args.duration,
            hz=args.hz,
        )
        print(
            f"live view: {st['frames']} frames, {st['steps']} steps logged (the mechanism "
            f"drawn at {st['drawn_steps']}; {st['thinned_frames']} frames behind the run "
            f"drew it thinned), to t = "
            f"{st['last_t'] if st['last_t'] is not None else float('nan'):.4g} s; lag "
            f"(newest simulated time received - newest logged) at most "
            f"{st['max_lag_s'] * 1e3:.1f} ms; a frame's work p50 "
            f"{st['frame_work_p50_s'] * 1e3:.2f} ms, max {st['frame_work_max_s'] * 1e3:.2f} ms"
        )
        if web is not None:
            _serve_until_interrupted(web)
        return 0
    if not args.recording:
        raise SystemExit("mps view: give a recording (RECORDING.mcap), or --live")
    from ..view.offline import view

    check_outputs({"--save": args.save}, inputs=[args.recording], force=args.force)

    scene = load_scene(args.scene) if args.scene else None
    save = args.save
    if args.web and save is None:  # the .rrd the web viewer serves, in a temporary folder
        import tempfile
        from pathlib import Path

        save = Path(tempfile.mkdtemp(prefix="mps-view-")) / (Path(args.recording).stem + ".rrd")
    saved, _ = view(args.recording, save=save, spawn=not (args.no_spawn or args.web), scene=scene)
    if args.web:
        _serve_until_interrupted(_web(saved, args.web_port))
    return 0


def _web(rrd, port: int):
    """Rerun's web viewer started on 127.0.0.1, its address said."""
    from ..view.web import WebViewer

    web = WebViewer(rrd, port)
    print(f"web viewer: {web.url} (listening on 127.0.0.1 only; Ctrl-C to stop)", flush=True)
    return web


def _serve_until_interrupted(web) -> None:
    """Serve until Ctrl-C or SIGTERM (the viewer then ended; the interruption goes on to mps's
    own line)."""
    import signal

    from mps_core.errors import raise_interrupted

    old = signal.signal(signal.SIGTERM, raise_interrupted)
    try:
        code = web.wait()
    finally:
        web.close()
        signal.signal(signal.SIGTERM, old)
    if code:
        raise SystemExit(f"mps view: the web viewer ended with exit status {code}")
