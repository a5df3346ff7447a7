"""The package's version, written once: pyproject.toml's."""

from __future__ import annotations


def _version() -> str:
    """The installed distribution's version: pyproject.toml's, the one place it is written
    (from that file itself where the tree runs without being installed)."""
    from importlib.metadata import PackageNotFoundError, version

    try:
        return version("mps")
    except PackageNotFoundError:
        import tomllib
        from pathlib import Path

        text = (Path(__file__).resolve().parents[1] / "pyproject.toml").read_text()
        return tomllib.loads(text)["project"]["version"]


__version__ = _version()
