"""Data flows one way: no module of mps_core or mps_ros imports, directly or through others
(imports inside functions included), a module that imports it; mps_core never imports ROS,
mcap or rerun."""

from __future__ import annotations

import ast
from pathlib import Path

ROOT = Path(__file__).resolve().parents[2]
PACKAGES = ("mps_core", "mps_ros")


def _modules() -> dict[str, Path]:
    out = {}
    for pkg in PACKAGES:
        for f in (ROOT / pkg).rglob("*.py"):
            rel = f.relative_to(ROOT).with_suffix("")
            parts = list(rel.parts)
            if parts[-1] == "__init__":
                parts = parts[:-1]
            out[".".join(parts)] = f
    return out


def _imports(name: str, path: Path, modules) -> set[str]:
    tree = ast.parse(path.read_text())
    is_pkg = path.name == "__init__.py"
    base = name.split(".") if is_pkg else name.split(".")[:-1]
    found = set()
    for node in ast.walk(tree):
        targets = []
        if isinstance(node, ast.Import):
            targets = [a.name for a in node.names]
        elif isinstance(node, ast.ImportFrom):
            if node.level:
                root = base[: len(base) - node.level + 1]
                mod = ".".join(root + ([node.module] if node.module else []))
            else:
                mod = node.module or ""
            targets = [mod] + [f"{mod}.{a.name}" for a in node.names]
        for t in targets:
            while t and t not in modules:
                t = t.rpartition(".")[0]
            if t and t != name and not name.startswith(t + "."):
                found.add(t)
    return found


def test_no_import_circle():
    modules = _modules()
    graph = {m: _imports(m, p, modules) for m, p in modules.items()}
    # packages' __init__ re-export their modules: leave them out of the circles
    graph = {
        m: {t for t in ts if Path(modules[t]).name != "__init__.py"}
        for m, ts in graph.items()
        if Path(modules[m]).name != "__init__.py"
    }
    state: dict[str, int] = {}
    stack: list[str] = []
    circles = []

    def visit(m):
        state[m] = 1
        stack.append(m)
        for t in sorted(graph.get(m, ())):
            if state.get(t) == 1:
                circles.append(stack[stack.index(t) :] + [t])
            elif t not in state:
                visit(t)
        stack.pop()
        state[m] = 2

    for m in sorted(graph):
        if m not in state:
            visit(m)
    assert not circles, "import circles: " + "; ".join(" -> ".join(c) for c in circles)


def test_the_core_imports_no_ros():
    for m, p in _modules().items():
        if not m.startswith("mps_core"):
            continue
        text = p.read_text()
        for word in ("rclpy", "import mcap", "from mcap", "rerun", "rosbags", "mps_ros"):
            lines = [
                ln for ln in text.splitlines() if ln.strip().startswith(("import", "from")) and word in ln
            ]
            assert not lines, (m, lines)


def test_the_core_names_no_ros_module():
    """Not even in a string or a docstring: the ROS side's commands and readers are found through
    entry points (``mps_core.plugins``), so no text of ``mps_core`` names a module of ``mps_ros``."""
    for m, p in _modules().items():
        if m.startswith("mps_core"):
            lines = [ln.strip() for ln in p.read_text().splitlines() if "mps_ros" in ln]
            assert not lines, (m, lines)


def test_the_commands_of_mps_ros_are_entry_points():
    """The entry points in pyproject.toml name modules that exist (the editable install reads them)."""
    import tomllib

    project = tomllib.loads((ROOT / "pyproject.toml").read_text())["project"]
    modules = _modules()
    for group in ("mps.commands", "mps.recordings", "mps.track_writers"):
        for name, target in project["entry-points"][group].items():
            module, _, attr = target.partition(":")
            assert module in modules, (group, name, target)
            assert f"def {attr}(" in modules[module].read_text(), (group, name, target)


#: mps_core's layers, lowest first: a module imports (at its top or inside a function) from its
#: own layer and the layers below only. The shared vocabulary (errors, names) and a child
#: process's pipe are below all;
#: ``mps_core`` itself (the public facade) is imported by the commands only.
LAYERS = (
    (
        "mps_core.errors",
        "mps_core.names",
        "mps_core.version",
        "mps_core.caches",
        "mps_core.plugins",
        "mps_core.child_process",
    ),
    ("mps_core.files",),
    ("mps_core.derivatives",),
    ("mps_core.solvers",),
    ("mps_core.model",),
    ("mps_core.scene",),
    ("mps_core.codegen",),
    ("mps_core.dynamics",),
    ("mps_core.run",),
    ("mps_core.track",),
    ("mps_core.analysis",),
    ("mps_core", "mps_core.cli", "mps_core.bench"),
)


def _layer(module: str) -> int:
    best, found = -1, -1
    for i, names in enumerate(LAYERS):
        for n in names:
            if (module == n or module.startswith(n + ".")) and len(n) > best:
                best, found = len(n), i
    assert found >= 0, f"{module} is in no layer of LAYERS"
    return found


def test_the_layers_import_downwards_only():
    modules = _modules()
    upward = []
    for m, p in modules.items():
        if not m.startswith("mps_core"):
            continue
        here = _layer(m)
        for t in sorted(_imports(m, p, modules)):
            if t.startswith("mps_core") and _layer(t) > here:
                upward.append(f"{m} (layer {here}) imports {t} (layer {_layer(t)})")
    assert not upward, "imports against the layers:\n" + "\n".join(upward)


#: mps_ros's layers, lowest first, by the same rule. Below ``mps_ros.ros`` nothing imports rclpy.
ROS_LAYERS = (
    ("mps_ros.os_threads",),
    ("mps_ros.wire",),
    ("mps_ros.recording",),
    # the Foxglove endpoint: served by the recording process (no rclpy, no engine)
    ("mps_ros.foxglove",),
    ("mps_ros.run",),
    ("mps_ros.ros",),
    ("mps_ros.view",),
    ("mps_ros", "mps_ros.commands", "mps_ros.bench"),
)


def _ros_layer(module: str) -> int:
    best, found = -1, -1
    for i, names in enumerate(ROS_LAYERS):
        for n in names:
            if (module == n or module.startswith(n + ".")) and len(n) > best:
                best, found = len(n), i
    assert found >= 0, f"{module} is in no layer of ROS_LAYERS"
    return found


def test_the_ros_layers_import_downwards_only():
    modules = _modules()
    upward = []
    for m, p in modules.items():
        if not m.startswith("mps_ros"):
            continue
        here = _ros_layer(m)
        for t in sorted(_imports(m, p, modules)):
            if t.startswith("mps_ros") and _ros_layer(t) > here:
                upward.append(f"{m} (layer {here}) imports {t} (layer {_ros_layer(t)})")
    assert not upward, "imports against the layers:\n" + "\n".join(upward)


def _imported_names(path: Path) -> set[str]:
    names = set()
    for node in ast.walk(ast.parse(path.read_text())):
        if isinstance(node, ast.Import):
            names |= {a.name for a in node.names}
        elif isinstance(node, ast.ImportFrom) and not node.level and node.module:
            names.add(node.module)
    return names


def test_rclpy_only_from_the_ros_layer_up():
    below = _ros_layer("mps_ros.ros")
    found = [
        m
        for m, p in _modules().items()
        if m.startswith("mps_ros")
        and _ros_layer(m) < below
        and any(n == "rclpy" or n.startswith("rclpy.") for n in _imported_names(p))
    ]
    assert not found, f"rclpy imported below mps_ros.ros: {found}"


def test_no_private_name_crosses_a_module():
    """``from X import _name`` only within a module's own package's tests: no module of mps_ros
    takes another's private name."""
    modules = _modules()
    crossing = []
    for m, p in modules.items():
        if not m.startswith("mps_ros"):
            continue
        for node in ast.walk(ast.parse(p.read_text())):
            if isinstance(node, ast.ImportFrom):
                crossing += [
                    f"{m}: {node.module}.{a.name}"
                    for a in node.names
                    if a.name.startswith("_") and not a.name.startswith("__")
                ]
    assert not crossing, "private names imported: " + ", ".join(crossing)


def test_every_layer_is_a_package_of_the_tree():
    for names in LAYERS + ROS_LAYERS:
        for n in names:
            path = ROOT / Path(*n.split("."))
            assert path.with_suffix(".py").is_file() or (path / "__init__.py").is_file(), n


def test_the_recording_process_does_without_the_engine():
    """The recording process (``python -m mps_ros.recording.background``, or with the Foxglove
    endpoint ``python -m mps_ros.foxglove.live``) writes files: importing it, and ``mps_core``
    itself, loads neither the engine nor scipy (a second's start here), nor rclpy."""
    import importlib.util
    import subprocess
    import sys

    for module in ("mps_ros.recording.background", "mps_ros.foxglove.live"):
        if module.startswith("mps_ros.foxglove") and importlib.util.find_spec("foxglove") is None:
            continue  # foxglove-sdk comes with the ros extra
        code = (
            f"import sys, mps_core, {module}; print(sorted(m for m in ('scipy', "
            "'mps_core.run.simulation', 'mps_core.scene', 'rclpy') if m in sys.modules))"
        )
        out = subprocess.run(
            [sys.executable, "-c", code], capture_output=True, text=True, check=True, cwd=ROOT
        )
        assert out.stdout.strip() == "[]", (module, out.stdout + out.stderr)
