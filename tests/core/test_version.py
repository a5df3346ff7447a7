"""The version is written once, in pyproject.toml: the package reports it, and the ROS package
manifest (which cannot read it) says the same."""

from __future__ import annotations

import re
import tomllib
from pathlib import Path

from mps_core import __version__

ROOT = Path(__file__).resolve().parents[2]


def test_the_version_is_pyprojects_everywhere():
    project = tomllib.loads((ROOT / "pyproject.toml").read_text())["project"]["version"]
    manifest = re.search(r"<version>([^<]+)</version>", (ROOT / "package.xml").read_text())
    assert __version__ == project == manifest.group(1)
