"""``mps view RECORDING.mcap [--save FILE.rrd] [--no-spawn] [--scene SCENE]``: a recording in
the Rerun viewer (:mod:`mps_ros.view`).

Without ``--save`` the .rrd goes to a temporary folder and the viewer opens on it; with
``--no-spawn`` it is only written. A viewer started here listens on 127.0.0.1 only.
``--scene`` gives the geometry for a recording that holds no scene metadata.
"""

from __future__ import annotations


def register(subparsers) -> None:
    p = subparsers.add_parser(
        "view", help="show a recording (MCAP) in the Rerun viewer, or save it as .rrd")
    p.add_argument("recording", metavar="RECORDING.mcap",
                   help="a recording from mps record or the node")
    p.add_argument("--save", metavar="FILE.rrd", help="write the Rerun recording to FILE.rrd")
    p.add_argument("--no-spawn", action="store_true",
                   help="do not open the viewer (with --save: only write the file)")
    p.add_argument("--scene", metavar="SCENE",
                   help="preset name or scene file for the geometry, if the recording has none")
    p.set_defaults(func=run)


def run(args) -> int:
    from .view import view

    scene = None
    if args.scene:
        from mps_core.scene import load_scene

        scene = load_scene(args.scene)
    view(args.recording, save=args.save, spawn=not args.no_spawn, scene=scene)
    return 0
