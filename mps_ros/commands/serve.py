"""``mps serve RECORDING [--port P] [--host H] [--rate R]``: a recording (a file or a bag) through
the node's Foxglove endpoint, played at real time or ``--rate`` times it, with Foxglove's play,
pause, speed and seek (:mod:`mps_ros.foxglove.serve`). Listens on 127.0.0.1 unless ``--host``
says otherwise."""

from __future__ import annotations

import argparse
import sys
from typing import Any


def register(subparsers: Any) -> None:
    p = subparsers.add_parser(
        "serve",
        help="serve a recording on a Foxglove WebSocket endpoint (Foxglove's live panels over a past run)",
    )
    p.add_argument("recording", metavar="RECORDING", help="a recording: an .mcap file or a bag directory")
    p.add_argument("--port", type=int, default=8765, help="the port (default 8765; 0: one the system picks)")
    p.add_argument(
        "--host",
        default="127.0.0.1",
        help="the address to listen on (default 127.0.0.1, this machine only; 0.0.0.0: every interface)",
    )
    p.add_argument("--rate", type=float, default=1.0, help="times real time (default 1; up to 1000)")
    p.add_argument(
        "--wait-clients",
        type=int,
        default=0,
        metavar="N",
        help="start playing once N clients have subscribed to every channel (default: at once)",
    )
    p.add_argument(
        "--exit-at-end",
        action="store_true",
        help="end at the recording's end (default: wait there for a seek, until Ctrl-C)",
    )
    p.set_defaults(func=run)


def run(args: argparse.Namespace) -> int:
    from ..foxglove.endpoint import EndpointError
    from ..foxglove.serve import ServeError, serve

    if args.wait_clients < 0:
        print(f"mps serve: error: --wait-clients {args.wait_clients}: expected 0 or more", file=sys.stderr)
        return 2
    try:
        serve(
            args.recording,
            host=args.host,
            port=args.port,
            rate=args.rate,
            wait_clients=args.wait_clients,
            wait_at_end=not args.exit_at_end,
        )
    except (ServeError, EndpointError) as exc:
        print(f"mps serve: error: {exc}", file=sys.stderr)
        return 2
    return 0
