"""What the code generators share: the writer of straight-line code, its loading, the passes
over its lines, and the engine's tables they read.

:mod:`mps_core.codegen.kernels` (central differences), :mod:`~mps_core.codegen.exact_kernels`
(exact derivatives), :mod:`~mps_core.codegen.fused_kernels` (the effects folded in) and
:mod:`~mps_core.codegen.reaction_kernels` (the joint reactions) write Python source through a
:class:`Writer` (one local per distinct expression), trim and fold it (:func:`live_lines`,
:func:`inline_once`) and compile it once per key (:func:`load`, keyed by :func:`kernel_key` and
:func:`function_key`). What they read of a mechanism comes from the engine as one frozen
:class:`Tables`, never from its private attributes.
"""

from __future__ import annotations

import hashlib
import math
import re
import types
import weakref
from collections.abc import Mapping
from dataclasses import dataclass, field
from types import MappingProxyType

import numpy as np

from ..caches import Memo
from ..derivatives.tracing import BranchChanged
from . import disk_cache

__all__ = [
    "COMPARE",
    "INFIX",
    "MAX_N",
    "Tables",
    "Writer",
    "function_key",
    "inline_once",
    "is_name",
    "kernel_key",
    "live_lines",
    "load",
    "made",
    "view_arguments",
]

#: charts with at most this many free coordinates get a kernel (the stencil grows as 2n²)
MAX_N = 2


@dataclass(frozen=True, eq=False)
class Tables:
    """What generated code reads of an engine's mechanism, fixed when the engine is made.

    ``point_names``: the mechanism's points, in the order of the position function's outputs;
    ``names``: every named row (the points, then ``G_<body>`` for each centre of mass) by its
    row number; ``body_index``: the bodies by name; ``mass``, ``inertia``: by body; ``rot``:
    the rotating bodies' numbers; ``MT``: the linear map from the points' coordinates to the
    named rows, the rotating bodies' link vectors and a finiteness check (transposed, see
    :class:`~mps_core.dynamics.maps.MechanismMaps`); ``offset``: the centres of mass' constant
    offsets (None: all zero); ``fixed_points``: the mechanism's fixed points. ``npoints`` (named rows) and
    ``npts`` (points) are counts; ``number`` is equal for equal tables in a process, ``digest``
    for equal tables in any process (what generated code is keyed by: the SHA-256 of them all,
    or a value of the process's own where one cannot be written out)."""

    point_names: tuple[str, ...]
    names: Mapping[str, int]
    body_index: Mapping[str, int]
    mass: np.ndarray
    inertia: np.ndarray
    rot: tuple[int, ...]
    MT: np.ndarray
    offset: np.ndarray | None
    fixed_points: tuple = ()
    npoints: int = field(init=False)
    npts: int = field(init=False)
    number: int = field(init=False)
    digest: object = field(init=False)

    def __post_init__(self):
        put = object.__setattr__
        put(self, "names", MappingProxyType(dict(self.names)))
        put(self, "body_index", MappingProxyType(dict(self.body_index)))
        put(self, "npoints", len(self.names))
        put(self, "npts", len(self.point_names))
        put(self, "number", _tables_number(self))
        put(self, "digest", _tables_digest(self))


class Writer:
    """Straight-line code with one local per distinct expression."""

    def __init__(self):
        self.lines: list[str] = []
        self.names: dict = {}

    def let(self, expr: str) -> str:
        if expr in self.names:
            return self.names[expr]
        if is_name(expr):
            return expr
        name = f"v{len(self.names)}"
        self.lines.append(f"    {name} = {expr}")
        self.names[expr] = name
        return name


def is_name(expr: str) -> bool:
    return expr.replace("_", "a").isalnum() and not expr[0].isdigit()


#: compiled kernels by what their code depends on (a run builds its engine afresh; the code of
#: an equal mechanism, view and Δ, or traced program, is the same)
_CODE = Memo("codegen.emitter.code", 1024)
_SERIAL = [0]


def load(key, source, label: str, flat, chart: str, extra: dict | None = None, depends=()):
    """The function ``kernel`` of generated code, compiled once per ``key`` (``source()`` gives
    the code; :func:`made`, ``depends``: what the code depends on besides ``key``). Its
    namespace: ``F`` (the position function), math's ``cos``, ``sin``, ``sqrt``, and
    ``_miss(*args)``, what a failed guard calls: the position function at ``args``, which
    raises its own error where the point is outside its domain; otherwise
    :class:`~mps_core.derivatives.tracing.BranchChanged`; and what ``extra`` adds."""
    code = _CODE.get(key)
    if code is None:
        compiled, src = made(key, source, label, depends)
        _SERIAL[0] += 1
        code = _CODE.keep(key, (compiled, src, _SERIAL[0]))

    def miss(*a):
        flat(*a)
        raise BranchChanged(chart)

    namespace = {"F": flat, "cos": math.cos, "sin": math.sin, "sqrt": math.sqrt, "_miss": miss}
    namespace.update(extra or {})
    exec(code[0], namespace)
    kernel = namespace["kernel"]
    kernel.source = code[1]
    #: a number of its own for each code made (never given twice): a short key for tables
    kernel.serial = code[2]
    return kernel


def made(key, source, label: str, depends=()) -> tuple:
    """Return (code object, source text) of generated code: the disk cache's entry for (``key``,
    ``label``, ``depends``) where it holds a valid one, else ``source()`` generated and
    compiled as ``label`` (and written there). ``key`` and ``depends`` together determine the
    source: the entry is what a generation here would give."""
    entry = disk_cache.entry("code", (key, label, depends))
    if entry is not None:
        hit = disk_cache.code_from(entry.read())
        if hit is not None:
            return hit
    src = source()
    disk_cache.COUNTS["generated"] += 1
    code = compile(src, label, "exec")
    if entry is not None:
        entry.write(disk_cache.code_items(src, code))
    return code, src


_FUNCTION_KEYS: weakref.WeakKeyDictionary = weakref.WeakKeyDictionary()


def function_key(fn, _depth: int = 0):
    """:func:`_function_key`, kept per function object."""
    try:
        return _FUNCTION_KEYS[fn]
    except (KeyError, TypeError):
        pass
    key = _function_key(fn, _depth)
    try:
        _FUNCTION_KEYS[fn] = key
    except TypeError:
        pass
    return key


def _function_key(fn, _depth: int = 0):
    """What a position function computes, as a hashable value: its code, module, defaults and
    the values its closure holds (numbers, strings, functions of the same kind; its module's
    globals are taken as fixed); None where the closure holds anything else (its generated
    code is then not shared between mechanisms)."""

    def value(x):
        if x is None or isinstance(x, (bool, int, float, str)):
            return x
        if isinstance(x, tuple):
            return tuple(value(y) for y in x)
        if isinstance(x, types.FunctionType):
            if _depth > 4:
                raise TypeError
            k = function_key(x, _depth + 1)
            if k is None:
                raise TypeError
            return k
        if isinstance(x, types.BuiltinFunctionType):
            return x
        raise TypeError

    try:
        cells = tuple(value(c.cell_contents) for c in fn.__closure__ or ())
        defaults = tuple(value(d) for d in fn.__defaults__ or ())
    except (TypeError, ValueError):  # ValueError: an empty cell
        return None
    return (_code_number(fn.__code__), fn.__module__, cells, defaults)


#: code objects by identity -> (the object, kept alive so that its id is not reused; a number)
_CODES: dict = {}


def _code_number(code) -> int:
    """A number of a code object's own (hashing the object itself walks its bytecode)."""
    hit = _CODES.get(id(code))
    if hit is None:  # kept: its id is not given to another object
        hit = _CODES[id(code)] = (code, len(_CODES) + 1)
    return hit[1]


_LOCAL = re.compile(r"\b[A-Za-z_][A-Za-z_0-9]*\b")


def live_lines(lines: list[str], ret: str) -> list[str]:
    """The lines of straight-line code that the return line and the guards need: an
    assignment whose local nothing later reads is left out (the forward pass computes every
    derivative of every node; the reactions read a part of them)."""
    needed = set(_LOCAL.findall(ret))
    keep = []
    for line in reversed(lines):
        body = line.strip()
        target, eq, expr = body.partition(" = ")
        if eq and not body.startswith("if ") and "," not in target:
            if target not in needed:
                continue
            needed.update(_LOCAL.findall(expr))
        else:  # a guard or an unpacking: always kept
            needed.update(_LOCAL.findall(body))
        keep.append(line)
    return keep[::-1]


def inline_once(lines: list[str]) -> list[str]:
    """Straight-line code with each local that is read once written into the line that reads
    it, in parentheses: the same operations in the same order, without storing and loading it.
    ``lines``: assignments ``    name = expr``, unpackings (``    a, b = x``: their targets
    stay), guards (``    if …``) and a last ``    return …``. Only later lines read a local,
    so an expression only moves forward (past guards, never before one)."""
    uses: dict = {}
    for line in lines:
        text = line.strip()
        target, eq, expr = text.partition(" = ")
        if not eq or text.startswith(("if ", "return ")) or "," in target:
            expr = text if not eq or text.startswith(("if ", "return ")) else expr
        for name in _LOCAL.findall(expr):
            uses[name] = uses.get(name, 0) + 1
    subst: dict = {}

    def put(expr: str) -> str:
        return _LOCAL.sub(lambda m: subst.pop(m.group(0), m.group(0)), expr)

    out = []
    for line in lines:
        text = line.strip()
        target, eq, expr = text.partition(" = ")
        if not eq or text.startswith(("if ", "return ")) or "," in target:
            if eq and "," in target and not text.startswith(("if ", "return ")):
                out.append(f"    {target} = {put(expr)}")
            else:
                out.append("    " + put(text))
            continue
        expr = put(expr)
        if uses.get(target, 0) == 1:
            subst[target] = expr if _LOCAL.fullmatch(expr) else f"({expr})"
        else:
            out.append(f"    {target} = {expr}")
    return out


def view_arguments(view, q):
    """(the position function's arguments at q: the view's template values and q,
    {argument position: traced input number})."""
    args, free = [], {}
    k_of = {ci: k for k, ci in enumerate(view.free)}
    for ci in range(view.chart.size):
        if ci in k_of:
            free[ci] = k_of[ci]
            args.append(float(q[k_of[ci]]))
        else:
            args.append(float(view._template[ci]))
    return args, free


#: the tape's arithmetic operations as Python's infix operators
INFIX = {"add": "+", "sub": "-", "mul": "*", "div": "/"}
#: the tape's comparisons as Python's
COMPARE = {"gt": ">", "ge": ">=", "lt": "<", "le": "<=", "eq": "==", "ne": "!="}


def kernel_key(engine, view, plan=None) -> tuple:
    """What a kernel's code depends on besides its own program (``plan``: the stencil's Δ)."""
    return (
        engine.tables.digest,
        view.chart.name,
        view.chart.size,
        tuple(view.free),
        tuple(view._template),
        None if plan is None else plan.d.tobytes(),
    )


#: the engines' tables by a number (never cleared: one per kind of mechanism)
_TABLES: dict = {}


def _tables_kind(tables: Tables) -> tuple:
    """Return what makes two tables equal for generated code."""
    off = None if tables.offset is None else tables.offset.tobytes()
    return (
        tables.MT.shape,
        tables.MT.tobytes(),
        off,
        tables.mass.tobytes(),
        tables.inertia.tobytes(),
        tables.rot,
        tables.point_names,
        tables.fixed_points,
    )


def _tables_number(tables: Tables) -> int:
    kind = _tables_kind(tables)
    number = _TABLES.get(kind)
    if number is None:
        number = _TABLES[kind] = len(_TABLES) + 1
    return number


#: what a key holds in place of a digest that cannot be written out (the disk cache refuses it)
_OWN = object()


def _tables_digest(tables: Tables):
    """Return the tables' SHA-256, with their arrays' types and the names of their rows and bodies; a
    value of this process's own (the tables' number beside :data:`_OWN`) where a part cannot be
    written out exactly."""
    h = hashlib.sha256()
    arrays = (tables.MT, tables.mass, tables.inertia) + (() if tables.offset is None else (tables.offset,))
    try:
        h.update(
            disk_cache.key_bytes(
                (
                    _tables_kind(tables),
                    tuple(a.dtype.str for a in arrays),
                    tuple(tables.names.items()),
                    tuple(tables.body_index.items()),
                )
            )
        )
    except TypeError:
        return (_OWN, tables.number)
    return h.hexdigest()
