"""The Node.js packages of tests/js (the Foxglove protocol's own client, puppeteer-core),
installed there with ``npm ci`` from its package-lock.json, once (again where the lock is
newer than the install)."""

from __future__ import annotations

import shutil
import subprocess
from pathlib import Path

JS = Path(__file__).resolve().parents[1] / "js"


def npm_ci() -> str | None:
    """Install tests/js's packages where they are not: None, or why they cannot be (no node or
    npm, the install failed)."""
    node, npm = shutil.which("node"), shutil.which("npm")
    if node is None or npm is None:
        return "node and npm are needed for the clients in tests/js"
    lock = JS / "package-lock.json"
    stamp = JS / "node_modules" / ".package-lock.json"
    if stamp.is_file() and stamp.stat().st_mtime >= lock.stat().st_mtime:
        return None
    p = subprocess.run(
        [npm, "ci", "--no-audit", "--no-fund"], cwd=JS, capture_output=True, text=True, timeout=600
    )
    if p.returncode != 0:
        return f"npm ci in tests/js failed (no registry?): {p.stderr.strip()[-400:]}"
    return None
