"""The house's rules, checked mechanically on relmap's sources (docs/architecture.md).

- One implementation per computation: no numba or llvmlite anywhere in ``src/relmap`` (the
  compiled loops live in ``relmap._core``, C++ built by ``pip install .``), no module of kernels
  beside a numpy path (``*_kernels.py``, ``_numba*.py``), no dispatch by size or environment
  (``RELMAP_NUMBA``, ``LARGE``, ``os.environ``), and no code written out in two functions.
- The layers: a module imports only from modules in its own layer or the layers below it,
  counting every import (module level, in functions, and under ``TYPE_CHECKING``), parsed
  with :mod:`ast`; and no import cycle joins two modules.
- One registration point per extension: a model (a subclass of ``relmap.models.base``'s
  protocols) is defined and exported in ``relmap.models`` and the filter names none; a loss
  lives in ``relmap.network.losses``; a format enters ``relmap.io.formats.register`` at the top
  level of the io module that defines its reader and writer, every entry point reads and writes
  through the registry, and no code elsewhere branches on a format's name.
- One name per thing (no alias imports, options as enums defined once), benchmarks and studies
  on the public API, the solvers reading a map through its stated interface, and the data walks
  of ``relmap query``, ``eval`` and ``localize`` going down the layers and coming back.

The checkers these rely on are tested themselves: the import parser on relmap's own imports,
and the twin, public-API, model and walk checkers on planted violations.
"""

from __future__ import annotations

import ast
import functools
from collections.abc import Iterator
from pathlib import Path
from types import FrameType
from typing import NamedTuple

import pytest

SRC = Path(__file__).resolve().parent.parent / "src"
PACKAGE = SRC / "relmap"

#: Layers, bottom-up (docs/architecture.md): a module may import from its layer and those below.
#: A name covers the module and, for a package, everything in it.
LAYERS: list[tuple[str, tuple[str, ...]]] = [
    ("base", ("errors", "typing", "_version", "_layout", "_core")),
    ("lie", ("lie",)),
    ("uncertain", ("uncertain",)),
    ("models", ("models",)),
    ("network", ("network",)),
    ("filter", ("filter",)),
    ("io", ("io",)),
    ("evaluate", ("evaluate",)),
    ("sim", ("sim",)),
    ("viz", ("viz",)),
    ("app", ("app", "__main__")),
]

#: Still true on this branch, being removed by other parts of issue 17 (the integrator removes
#: an entry when its part is merged): module -> why.
PENDING_NUMBA: dict[str, str] = {}
PENDING_LAYERS: dict[str, str] = {}


def _module_name(path: Path) -> str:
    parts = list(path.relative_to(SRC).with_suffix("").parts)
    if parts[-1] == "__init__":
        parts.pop()
    return ".".join(parts)


MODULES = {_module_name(p): p for p in sorted(PACKAGE.rglob("*.py"))}


def _resolve(name: str) -> str:
    """The longest prefix of ``name`` that is one of relmap's modules (or ``name``)."""
    parts = name.split(".")
    for k in range(len(parts), 0, -1):
        candidate = ".".join(parts[:k])
        if candidate in MODULES or candidate == "relmap._core":
            return candidate
    return name


@functools.cache
def tree(module: str) -> ast.Module:
    """The parsed source of ``module`` (parsed once per test process)."""
    return ast.parse(MODULES[module].read_text(encoding="utf-8"))


@functools.cache
def imports(module: str) -> frozenset[str]:
    """Every module that ``module`` imports (anywhere in its source), resolved to relmap's
    modules where they are relmap's; others by their top-level name."""
    path = MODULES[module]
    package = module if path.name == "__init__.py" else module.rpartition(".")[0]
    out: set[str] = set()
    for node in ast.walk(tree(module)):
        if isinstance(node, ast.Import):
            out.update(
                _resolve(a.name) if a.name.startswith("relmap") else a.name.split(".")[0]
                for a in node.names
            )
        elif isinstance(node, ast.ImportFrom):
            if node.level:
                base = package.split(".")[: len(package.split(".")) - node.level + 1]
                source = ".".join([*base, *([node.module] if node.module else [])])
            else:
                source = node.module or ""
            if not source.startswith("relmap"):
                out.add(source.split(".")[0])
                continue
            for alias in node.names:  # `from relmap import gaussian` names a module
                target = f"{source}.{alias.name}"
                is_module = target in MODULES or target == "relmap._core"
                out.add(target if is_module else _resolve(source))
    return frozenset(out)


@functools.cache
def layer_of(module: str) -> int:
    """The index of ``module``'s layer; fails for a module that has none."""
    inner = module.removeprefix("relmap.")
    for index, (_, names) in enumerate(LAYERS):
        if any(inner == n or inner.startswith(n + ".") for n in names):
            return index
    raise AssertionError(
        f"{module} is in no layer: add it to LAYERS here and to docs/architecture.md"
    )


def _marked(module: str, reason: str | None) -> object:
    if reason is None:
        return module
    return pytest.param(module, marks=pytest.mark.xfail(reason=reason, strict=False))


def _numba_reason(module: str) -> str | None:
    return PENDING_NUMBA.get(module)


LIBRARY = [m for m in MODULES if m != "relmap"]


@pytest.mark.parametrize("module", [_marked(m, _numba_reason(m)) for m in MODULES])
def test_no_numba_and_no_dispatch_by_size_or_environment(module):
    used = imports(module)
    assert not used & {"numba", "llvmlite"}, f"{module} imports numba/llvmlite"
    assert not used & {"relmap._numba", "relmap._numba_math"}, f"{module} dispatches on numba"
    text = MODULES[module].read_text(encoding="utf-8")
    for word in ("RELMAP_NUMBA", "ONE_SHOT_LARGE", "_numba.LARGE", "os.environ", "getenv"):
        assert word not in text, f"{module} mentions {word}: a switch between implementations"


def test_no_module_of_kernels_beside_a_numpy_path():
    twins = [m for m in MODULES if m.rpartition(".")[2].endswith("_kernels")]
    numba = [m for m in MODULES if m.rpartition(".")[2].startswith("_numba")]
    pending = {m for m in twins + numba if _numba_reason(m)}
    assert set(twins + numba) <= pending, f"kernel modules beside numpy paths: {twins + numba}"


@pytest.mark.parametrize("module", [_marked(m, PENDING_LAYERS.get(m)) for m in LIBRARY])
def test_a_module_imports_only_from_its_layer_and_below(module):
    mine = layer_of(module)
    above = sorted(
        f"{other} ({LAYERS[layer_of(other)][0]})"
        for other in imports(module)
        if other.startswith("relmap") and other != "relmap" and layer_of(other) > mine
    )
    assert not above, f"{module} ({LAYERS[mine][0]}) imports from layers above it: {above}"
    if "relmap" in imports(module):  # the package's namespace re-exports every layer
        assert LAYERS[mine][0] == "app", f"{module} imports the relmap package itself"


def _cycles() -> list[list[str]]:
    graph = {m: sorted(i for i in imports(m) if i in MODULES and i != "relmap") for m in LIBRARY}
    index: dict[str, int] = {}
    low: dict[str, int] = {}
    stack: list[str] = []
    on: set[str] = set()
    found: list[list[str]] = []

    def visit(v: str) -> None:  # Tarjan's strongly connected components
        index[v] = low[v] = len(index)
        stack.append(v)
        on.add(v)
        for w in graph[v]:
            if w not in index:
                visit(w)
                low[v] = min(low[v], low[w])
            elif w in on:
                low[v] = min(low[v], index[w])
        if low[v] == index[v]:
            component = []
            while True:
                w = stack.pop()
                on.discard(w)
                component.append(w)
                if w == v:
                    break
            if len(component) > 1:
                found.append(sorted(component))

    for v in graph:
        if v not in index:
            visit(v)
    return found


def test_the_layer_map_knows_every_module():
    for module in LIBRARY:
        layer_of(module)


def test_no_import_cycles():
    """No import cycle joins two modules (a function-level or ``TYPE_CHECKING`` import counts)."""
    assert _cycles() == [], f"import cycles: {_cycles()}"


def test_the_import_parser_sees_relmaps_imports():
    """What the checks above rely on: every form of import is seen and resolved."""
    assert "relmap._core" in imports("relmap.uncertain.at3")  # from relmap import _core (compiled)
    assert "relmap.errors" in imports("relmap.uncertain.gaussian")  # from relmap.errors import ...
    assert "relmap.lie.group" in imports("relmap.uncertain.at3")  # from relmap.lie.group import SE3
    assert "relmap.lie.se3" in imports("relmap.uncertain.at3")  # from relmap.lie import se3
    assert "relmap.evaluate" in imports("relmap.app.trajectory")  # a package's own name
    assert "relmap.network.graph" in imports("relmap.io.maps")  # in a function or at the top
    assert "relmap" in imports("relmap.app.cli")  # from relmap import __version__: the package
    assert "numpy" in imports("relmap.uncertain.gaussian")
    assert layer_of("relmap.io.posegraph") > layer_of("relmap.network.graph")


SOLVERS = ("relmap.network.query", "relmap.network.optimal", "relmap.network.sensing")


def test_the_solvers_read_a_map_through_its_stated_interface():
    """The map sits above its solvers: they import no ``network.graph`` and read a map ``g``
    only through the members :class:`relmap.network.parts.MapView` / ``EditableMap`` state."""
    from relmap.network.parts import EditableMap

    stated = {
        name
        for cls in EditableMap.__mro__
        for name in vars(cls)
        if not name.startswith("_") or name == "__contains__"
    }
    for module in SOLVERS:
        assert "relmap.network.graph" not in imports(module), f"{module} imports the map"
        read = {
            node.attr
            for node in ast.walk(tree(module))
            if isinstance(node, ast.Attribute)
            and isinstance(node.value, ast.Name)
            and node.value.id in ("g", "trial")
        }
        assert read, f"{module}: no map read found (the check would be vacuous)"
        assert read <= stated, f"{module} reads {sorted(read - stated)} off the map"


# ----------------------------------------------------------------------- no twins in src/
#: A copy is this many statements in a row of one function's body, spanning at least this many
#: lines, that also occur in another function (local names canonicalized, so a copy with
#: renamed variables is still one; docstrings and annotations ignored).
TWIN_STATEMENTS, TWIN_LINES = 3, 4
#: Copies still in src/, each to go (the integrator removes an entry when its fix lands; the
#: check below fails both on a new copy and on a listed one that is gone): functions -> why.
KNOWN_TWINS: dict[frozenset[str], str] = {}


_SHAPES: dict[ast.stmt, tuple[str, list[str]]] = {}


def _shape(node: object, names: list[str]) -> str:
    """``node`` written out with its names and arguments blanked (their order of use appended
    to ``names``) and annotations dropped: copies with renamed variables have one shape."""
    if isinstance(node, ast.Name):
        names.append(node.id)
        return "N"
    if isinstance(node, ast.arg):
        names.append(node.arg)
        return "A"
    if isinstance(node, ast.stmt) and node in _SHAPES:  # a nested function's, seen before
        text, used = _SHAPES[node]
        names.extend(used)
        return text
    if isinstance(node, ast.AST):
        fields = (
            _shape(value, names)
            for field, value in ast.iter_fields(node)
            if field not in ("annotation", "returns", "type_comment", "ctx")
        )
        return f"{type(node).__name__}({','.join(fields)})"
    if isinstance(node, list):
        return f"[{','.join(_shape(v, names) for v in node)}]"
    return repr(node)


def _functions(tree: ast.AST, prefix: str) -> Iterator[tuple[str, ast.AST]]:
    """Every function and method of ``tree`` with its qualified name."""
    for node in ast.iter_child_nodes(tree):
        if isinstance(node, (ast.FunctionDef, ast.AsyncFunctionDef, ast.ClassDef)):
            name = f"{prefix}.{node.name}"
            if not isinstance(node, ast.ClassDef):
                yield name, node
            yield from _functions(node, name)
        else:
            yield from _functions(node, prefix)


def twins(sources: dict[str, ast.Module]) -> dict[frozenset[str], list[str]]:
    """Copies of code between functions of ``sources`` (module name -> parsed source): each
    set of two or more functions that share a run of :data:`TWIN_STATEMENTS` statements
    spanning :data:`TWIN_LINES` lines, with where each copy starts."""
    seen: dict[tuple[tuple[str, ...], tuple[int, ...]], list[tuple[str, int]]] = {}
    for module, parsed in sources.items():
        for name, fn in reversed(list(_functions(parsed, module))):  # nested ones first
            body = fn.body  # type: ignore[attr-defined]
            if body and isinstance(body[0], ast.Expr) and isinstance(body[0].value, ast.Constant):
                body = body[1:]  # the docstring
            shapes = []
            for statement in body:
                names: list[str] = []
                _SHAPES[statement] = (_shape(statement, names), names)
                shapes.append(_SHAPES[statement])
            for k in range(len(body) - TWIN_STATEMENTS + 1):
                run = body[k : k + TWIN_STATEMENTS]
                if run[-1].end_lineno - run[0].lineno + 1 < TWIN_LINES:  # type: ignore[operator]
                    continue
                order: dict[str, int] = {}  # names by first use within the run
                used = tuple(
                    order.setdefault(n, len(order))
                    for _, names in shapes[k : k + TWIN_STATEMENTS]
                    for n in names
                )
                key = (tuple(dump for dump, _ in shapes[k : k + TWIN_STATEMENTS]), used)
                seen.setdefault(key, []).append((name, run[0].lineno))
    found: dict[frozenset[str], list[str]] = {}
    for places in seen.values():
        functions = frozenset(name for name, _ in places)
        if len(functions) > 1:
            found.setdefault(functions, []).extend(f"{n}:{line}" for n, line in places)
    return found


@functools.cache
def _src_twins() -> dict[frozenset[str], list[str]]:
    return twins({m: tree(m) for m in MODULES})


def test_src_has_no_twins():
    """No run of statements is written out in two functions of src/ (one implementation of
    every computation), except the copies listed in KNOWN_TWINS."""
    found = _src_twins()
    new = {", ".join(sorted(f)): where for f, where in found.items() if f not in KNOWN_TWINS}
    assert not new, f"code copied between functions (make one call the other): {new}"


def test_the_known_twins_are_still_there():
    """KNOWN_TWINS stays true: an entry whose copy is gone is to be removed."""
    gone = [", ".join(sorted(f)) for f in KNOWN_TWINS if f not in _src_twins()]
    assert not gone, f"these copies are gone; remove them from KNOWN_TWINS: {gone}"


def test_the_twin_check_finds_a_renamed_copy():
    """What the check above relies on: a block copied with other variable names is found,
    across modules and within one, and different code is not."""
    original = '''
def joint(C, b, k):
    """Doc."""
    eye = np.eye(b)
    D = np.zeros((b * (k - 1), b * k))
    for j in range(1, k):
        D[b * (j - 1) : b * j, :b] = -eye
    return D @ C @ D.T
'''
    renamed = """
class Merger:
    def weights(self, joint: float, size, count):
        identity = np.eye(size)
        Diff = np.zeros((size * (count - 1), size * count))
        for i in range(1, count):
            Diff[size * (i - 1) : size * i, :size] = -identity
        return None
"""
    other = """
def unrelated(C, b, k):
    eye = np.eye(b)
    D = np.ones((b * (k - 1), b * k))
    for j in range(1, k):
        D[b * (j - 1) : b * j, :b] = -eye
    return D @ C @ D.T
"""
    found = twins({"a": ast.parse(original), "b": ast.parse(renamed), "c": ast.parse(other)})
    assert set(found) == {frozenset({"a.joint", "b.Merger.weights"})}
    one = twins({"a": ast.parse(original + renamed)})
    assert set(one) == {frozenset({"a.joint", "a.Merger.weights"})}


# ------------------------------------------------ benchmarks and studies use relmap as users do
ROOT = SRC.parent
#: Scripts that use relmap as a user does: the benchmarks against peers and the executable notes.
USER_SCRIPTS = sorted(
    [*(ROOT / "benchmarks").glob("*.py"), *(ROOT / "docs" / "studies").glob("*.py")]
)
#: Underscored names that are public API: a NamedTuple's methods and fields.
NAMEDTUPLE_API = frozenset({"_replace", "_asdict", "_fields", "_make", "_field_defaults"})


def _private(dotted: str) -> bool:
    return any(p.startswith("_") and not p.startswith("__") for p in dotted.split("."))


def non_user_uses(source: str) -> list[str]:
    """What a script uses that a user of relmap cannot: a private module or name (``_core``,
    ``_x``; a NamedTuple's ``_replace`` and its kin are public), the test suite (``tests``,
    ``conftest``), a relative import, or ``sys.path``."""
    found = []
    for node in ast.walk(ast.parse(source)):
        modules: list[str] = []
        if isinstance(node, ast.Import):
            modules = [a.name for a in node.names]
        elif isinstance(node, ast.ImportFrom):
            if node.level:
                found.append(f"line {node.lineno}: a relative import")
            base = node.module or ""
            modules = [base, *(f"{base}.{a.name}" for a in node.names if a.name != "*")]
        elif isinstance(node, ast.Attribute):
            if _private(node.attr) and node.attr not in NAMEDTUPLE_API:
                found.append(f"line {node.lineno}: .{node.attr}")
            if node.attr == "path" and isinstance(node.value, ast.Name) and node.value.id == "sys":
                found.append(f"line {node.lineno}: sys.path")
        elif isinstance(node, ast.Constant) and isinstance(node.value, str):
            if node.value.startswith("relmap.") and node.value.isascii() and " " not in node.value:
                modules = [node.value]  # a module named in a string, for importlib
        found += [
            f"line {getattr(node, 'lineno', 0)}: {m}"
            for m in modules
            if _private(m) or m.split(".")[0] in ("tests", "conftest")
        ]
    return found


@pytest.mark.parametrize(
    "path", USER_SCRIPTS, ids=[f"{p.parent.name}/{p.name}" for p in USER_SCRIPTS]
)
def test_benchmarks_and_studies_use_only_the_public_api(path):
    assert non_user_uses(path.read_text(encoding="utf-8")) == []


def test_the_public_api_check_finds_what_a_user_cannot_use():
    script = """
import sys
sys.path.insert(0, "..")
from tests.conftest import data_dir
from relmap._core import compound3
from relmap.app.localize import _start, localize
import relmap.uncertain._sym3 as s
from . import helper
importlib.import_module("relmap._core")
a = rm.AT._trusted(m, c)
p = params._replace(k_s=1.0)._asdict()
print("relmap.io reads a file")
"""
    found = {f.split(": ", 1)[1] for f in non_user_uses(script)}
    assert found == {
        "sys.path",
        "tests.conftest",
        "tests.conftest.data_dir",
        "relmap._core",
        "relmap._core.compound3",
        "relmap.app.localize._start",
        "relmap.uncertain._sym3",
        "a relative import",
        "._trusted",
    }


# ------------------------------------------------------------- formats: one registration point
#: The library's entry points that read or write maps, pose graphs and trajectories: each goes
#: through the registry (relmap.io.formats), so a format registered there serves all of them.
FORMAT_ENTRY_POINTS = {
    "relmap.io.maps": ("load_map", "save_map"),
    "relmap.io.mapfile": ("read_records",),
    "relmap.io.posegraph": ("read_graph", "write_graph"),
    "relmap.io.trajectory": ("read_trajectory", "recognise_trajectory", "write_trajectory"),
}


def _registrations() -> dict[str, list[ast.Call]]:
    """Every ``register(...)`` call of src/relmap, by module."""
    found: dict[str, list[ast.Call]] = {}
    for module in MODULES:
        for node in ast.walk(tree(module)):
            if isinstance(node, ast.Call):
                name = getattr(node.func, "attr", getattr(node.func, "id", None))
                if name == "register":
                    found.setdefault(module, []).append(node)
    return found


def test_formats_have_one_registration_point():
    """Formats enter the registry only by ``formats.register(formats.Format(...))``, once per
    format, at the top level of the io module that defines its reader and writer; nothing else
    touches the registry, and every entry point reads or writes through it."""
    from relmap.io import formats

    calls = _registrations()
    assert set(calls) <= {m for m in MODULES if m.startswith("relmap.io.")}, set(calls)
    top_level = {
        id(node.value)
        for module in calls
        for node in tree(module).body
        if isinstance(node, ast.Expr) and isinstance(node.value, ast.Call)
    }
    for module, found in calls.items():
        for call in found:
            assert id(call) in top_level, f"{module}:{call.lineno}: register at the top level"
            (arg,) = call.args
            assert isinstance(arg, ast.Call) and getattr(arg.func, "attr", None) == "Format"
    registered = formats.formats()
    assert len(registered) == sum(map(len, calls.values())), "a format registered twice?"
    for fmt in registered:
        for function in (fmt.read, fmt.write):
            if function is None:
                continue
            function = getattr(function, "func", function)  # functools.partial
            assert function.__module__ in calls, f"{fmt.name}: {function} is not its module's"
            assert function.__name__ != "<lambda>", f"{fmt.name}: name its reader and writer"
    for module in MODULES:
        if module != "relmap.io.formats":
            text = MODULES[module].read_text(encoding="utf-8")
            assert "_REGISTRY" not in text, f"{module} reaches into the registry"
    for module, names in FORMAT_ENTRY_POINTS.items():
        functions = dict(_functions(tree(module), module))
        for name in names:
            uses = {
                node.attr
                for node in ast.walk(functions[f"{module}.{name}"])
                if isinstance(node, ast.Attribute) and getattr(node.value, "id", "") == "formats"
            }
            assert uses, f"{module}.{name} does not go through relmap.io.formats"


def test_no_code_branches_on_a_formats_name():
    """No ``fmt == "tum"`` or ``fmt in ("g2o", "toro")`` outside the module that registers that
    format (the registry dispatches; a format's own module may know its own names)."""
    from relmap.io import formats

    owner = {}
    for fmt in formats.formats():
        owner[fmt.name] = getattr(fmt.read, "func", fmt.read).__module__
    found = []
    for module in LIBRARY:
        for node in ast.walk(tree(module)):
            if not isinstance(node, ast.Compare):
                continue
            operands = [node.left, *node.comparators]
            constants = [
                c.value
                for side in operands
                for c in (side.elts if isinstance(side, (ast.Tuple, ast.List, ast.Set)) else [side])
                if isinstance(c, ast.Constant) and isinstance(c.value, str)
            ]
            found += [
                f"{module}:{node.lineno} {value!r}"
                for value in constants
                if value in owner and owner[value] != module
            ]
    assert not found, f"code branching on a format's name: {found}"


# -------------------------------------------------------------- one name per thing
def _bound_names(module: str) -> set[str]:
    """The names ``module`` defines itself at its top level (functions, classes, assignments;
    also inside top-level ``if``/``try`` blocks), not those it imports."""
    out: set[str] = set()
    todo: list[ast.stmt] = list(tree(module).body)
    while todo:
        node = todo.pop()
        if isinstance(node, (ast.FunctionDef, ast.AsyncFunctionDef, ast.ClassDef)):
            out.add(node.name)
        elif isinstance(node, (ast.Assign, ast.AnnAssign, ast.AugAssign)):
            targets = node.targets if isinstance(node, ast.Assign) else [node.target]
            out.update(n.id for t in targets for n in ast.walk(t) if isinstance(n, ast.Name))
        elif isinstance(node, (ast.If, ast.Try)):
            todo.extend(node.body + node.orelse + getattr(node, "finalbody", []))
            todo.extend(s for h in getattr(node, "handlers", []) for s in h.body)
    return out


def _imported_names(module: str) -> Iterator[tuple[int, str, str]]:
    """``(line, source module, name)`` of every ``from relmap… import name`` in ``module``."""
    path = MODULES[module]
    package = module if path.name == "__init__.py" else module.rpartition(".")[0]
    for node in ast.walk(tree(module)):
        if not isinstance(node, ast.ImportFrom):
            continue
        source = node.module or ""
        if node.level:
            base = package.split(".")[: len(package.split(".")) - node.level + 1]
            source = ".".join([*base, *([node.module] if node.module else [])])
        if source in MODULES:
            for alias in node.names:
                yield node.lineno, source, alias.name


@pytest.mark.parametrize("module", LIBRARY)
def test_library_code_imports_a_name_from_the_module_that_defines_it(module):
    """No alias modules: relmap's modules import each name from the module that defines it,
    never through a module that re-exports it (a package's ``__init__`` is the users' door,
    not relmap's; the applications may take ``__version__`` from the package)."""
    aliased = [
        f"line {line}: {name} from {source}"
        for line, source, name in _imported_names(module)
        if f"{source}.{name}" not in MODULES
        and f"{source}.{name}" != "relmap._core"
        and name not in _bound_names(source)
        and (source, name) != ("relmap", "__version__")
    ]
    assert not aliased, f"{module} imports names through a re-export: {aliased}"


#: Modules being rewritten now (issue 31: models/, filter/ and localize are the lead engineer's);
#: their options become Option enums there, and the checks below then cover them too.
PENDING_OPTIONS: tuple[str, ...] = ()


def _option_values() -> dict[str, frozenset[str]]:
    """Every :class:`relmap.typing.Option` of ``src/relmap`` (``module.Name``) and its values."""
    out: dict[str, frozenset[str]] = {}
    for module in MODULES:
        for node in ast.walk(tree(module)):
            if isinstance(node, ast.ClassDef) and any(
                isinstance(b, ast.Name) and b.id == "Option" for b in node.bases
            ):
                out[f"{module}.{node.name}"] = frozenset(
                    s.value.value
                    for s in node.body
                    if isinstance(s, ast.Assign)
                    and isinstance(s.value, ast.Constant)
                    and isinstance(s.value.value, str)
                )
    return out


def _pending(module: str) -> bool:
    return any(module == p or module.startswith(p + ".") for p in PENDING_OPTIONS)


@pytest.mark.parametrize("module", [m for m in LIBRARY if not _pending(m)])
def test_options_are_enums_defined_once(module):
    """An option is an :class:`relmap.typing.Option` (a str enum, parsed at the edge with an
    error listing its choices), not a ``Literal`` of strings, and its values are written once:
    no tuple, list, set or dict of two or more of one option's values elsewhere (a second
    list of choices, e.g. argparse's, reads them from the enum)."""
    options = _option_values()
    assert "relmap.uncertain.moments.MomentsMethod" in options  # (the check is not vacuous)
    found = []
    for node in ast.walk(tree(module)):
        if isinstance(node, ast.Subscript) and getattr(node.value, "id", "") == "Literal":
            words = [c.value for c in ast.walk(node.slice) if isinstance(c, ast.Constant)]
            if any(isinstance(w, str) for w in words):
                found.append(f"line {node.lineno}: Literal{words}")
        items = (
            node.keys
            if isinstance(node, ast.Dict)
            else node.elts
            if isinstance(node, (ast.Tuple, ast.List, ast.Set))
            else []
        )
        words = [c.value for c in items if isinstance(c, ast.Constant)]
        if len(words) >= 2 and all(isinstance(w, str) for w in words):
            for name, values in options.items():
                if set(words) <= values:
                    found.append(f"line {node.lineno}: {words} are {name}'s values again")
    assert not found, f"{module}: options written as strings: {found}"


# -------------------------------------------------------------------------- data walks
#: The commands whose data walk is measured, run in-process (``relmap.app.cli.main``);
#: ``{examples}`` is the examples folder and ``{tmp}`` a folder holding two small trajectories
#: (``ref.txt``, TUM; ``est.txt``, relmap's format with covariance); ``{mrclam}`` the first
#: :data:`MRCLAM_SECONDS` of the shared MRCLAM logs (a walk over the shared data carries the
#: ``real_data`` mark). ``relmap localize`` of the first minute goes through every stage of the
#: whole run (autocalibration, the filter, dead reckoning, the scores) in ~4 s instead of ~30 s.
WALKS = [
    pytest.param(["query", "{examples}/bridge.yaml", "w", "u"], id="query"),
    pytest.param(["eval", "{tmp}/ref.txt", "{tmp}/est.txt"], id="eval"),
    pytest.param(
        ["localize", "{mrclam}", "--robot", "1"], id="localize", marks=pytest.mark.real_data
    ),
]
MRCLAM_SECONDS = 60.0
#: Functions of a higher layer that a walk may call (callee -> why): a progress reporter,
#: which carries no data, and hooks still to be replaced by data (each with its fix).
CALLBACKS: dict[tuple[str, str], str] = {
    ("relmap.app.cli", "_localize.<locals>.<lambda>"): "relmap localize's progress bar",
    ("relmap.app.localize", "_localization.<locals>.start"): "autocalibration asks the "
    "application for the start pose (the truth at the first time) of every candidate clock "
    "offset: to go, the start handed down as data (the truth's times and poses)",
}
#: The AT algebra's modules: within them a walk goes down and comes back (each kind's steps in
#: its own module, the base calls no kind).
ALGEBRA = ("relmap.uncertain", "relmap.lie", "relmap._layout")


class Call(NamedTuple):
    """One call of a relmap function: who called (the nearest relmap function up the stack, so
    a callback through numpy or a builtin counts as called by the function that handed it on)
    and what was called, each as (module, qualified name)."""

    caller: tuple[str, str]
    callee: tuple[str, str]


def walk(argv: list[str]) -> list[Call]:
    """Every call of a relmap function while ``relmap argv`` runs (after a first run, so that
    lazy imports are done), in order, under :func:`sys.setprofile`."""
    import contextlib
    import io
    import sys

    from relmap.app.cli import main

    calls: list[Call] = []

    def profile(frame: FrameType, event: str, arg: object) -> None:
        if event != "call" or not frame.f_globals.get("__name__", "").startswith("relmap"):
            return
        up = frame.f_back
        while up is not None and not up.f_globals.get("__name__", "").startswith("relmap"):
            up = up.f_back
        if up is not None:
            calls.append(
                Call(
                    (up.f_globals["__name__"], up.f_code.co_qualname),
                    (frame.f_globals["__name__"], frame.f_code.co_qualname),
                )
            )

    with contextlib.redirect_stdout(io.StringIO()), contextlib.redirect_stderr(io.StringIO()):
        assert main(argv) == 0, f"relmap {' '.join(argv)} failed"
        sys.setprofile(profile)
        try:
            status = main(argv)
        finally:
            sys.setprofile(None)
    assert status == 0
    return calls


@functools.cache
def below(module: str) -> frozenset[str]:
    """The relmap modules ``module`` imports, directly or through others."""
    out: set[str] = set()
    for other in imports(module):
        if other in MODULES and other not in (module, "relmap"):
            out |= {other, *below(other)}
    return frozenset(out)


def upward(calls: list[Call]) -> list[Call]:
    """The calls from a layer to a higher one (LAYERS): only a callback, a hook defined higher
    up or a protocol method can make one."""
    return [c for c in calls if layer_of(c.callee[0]) > layer_of(c.caller[0])]


def climbs(calls: list[Call], within: tuple[str, ...] = ("relmap",)) -> list[Call]:
    """The calls between modules of ``within`` against the import graph: the callee's module
    imports the caller's (it sits above it), so the walk climbs back up."""
    inside = [c for c in calls if all(m.startswith(within) for m in (c.caller[0], c.callee[0]))]
    return [c for c in inside if c.caller[0] != c.callee[0] and c.caller[0] in below(c.callee[0])]


def switches(calls: list[Call], within: tuple[str, ...] = ALGEBRA) -> int:
    """How often the walk goes from one module of ``within`` into another (back and forth)."""
    return sum(
        c.caller[0] != c.callee[0] and all(m.startswith(within) for m in (c.caller[0], c.callee[0]))
        for c in calls
    )


def _walk_files(folder: Path, data: Path | None = None) -> dict[str, str]:
    """The placeholders of :data:`WALKS`, with the two trajectories written into ``folder``
    (and, given the shared ``data``, the start of its MRCLAM logs)."""
    import numpy as np

    from relmap.io.trajectory import write_trajectory
    from relmap.uncertain.trajectory import Trajectory

    t = np.arange(20) * 0.1
    xyz = np.stack([np.cos(t), np.sin(t), 0.1 * t], -1)
    q = np.tile([0.0, 0.0, 0.0, 1.0], (20, 1))
    write_trajectory(folder / "ref.txt", Trajectory.from_quaternions(xyz, q, t), "tum")
    M = Trajectory.from_quaternions(xyz + 0.01 * np.sin(7 * t)[:, None], q, t).matrices
    cov = np.broadcast_to(np.diag([1e-4] * 3 + [1e-6] * 3), (20, 6, 6))
    write_trajectory(folder / "est.txt", Trajectory.from_matrices(M, t, cov))
    places = {"examples": str(SRC.parent / "examples"), "tmp": str(folder)}
    if data is not None:  # every file of the MRCLAM folder, its robots' logs cut short
        (mrclam := folder / "mrclam").mkdir()
        for path in sorted((data / "landmarks" / "mrclam6").iterdir()):
            lines = path.read_text(encoding="utf-8").splitlines(keepends=True)
            if path.name.startswith("Robot"):
                rows = [line for line in lines if line.strip() and not line.startswith("#")]
                end = float(rows[0].split()[0]) + MRCLAM_SECONDS
                lines = [
                    ln
                    for ln in lines
                    if not ln.strip() or ln.startswith("#") or float(ln.split()[0]) < end
                ]
            (mrclam / path.name).write_text("".join(lines), encoding="utf-8")
        places["mrclam"] = str(mrclam)
    return places


@pytest.mark.parametrize("argv", WALKS)
def test_a_data_walk_goes_down_and_comes_back(argv, tmp_path, request):
    """A command's data walk goes down the layers and comes back: no call climbs to a higher
    layer (but the :data:`CALLBACKS`), and within the AT algebra no call climbs against the
    import graph (the kinds' steps each in their module, the base calling none of them)."""
    data = request.getfixturevalue("data_dir") if "{mrclam}" in argv else None
    places = _walk_files(tmp_path, data)
    calls = walk([a.format(**places) for a in argv])
    assert any(c.callee[0].startswith("relmap.uncertain") for c in calls)  # not vacuous
    up = sorted({c for c in upward(calls) if c.callee not in CALLBACKS})
    assert not up, f"calls up a layer: {up}"
    assert not climbs(calls, ALGEBRA), f"the AT algebra climbs: {sorted(set(climbs(calls)))}"


def test_the_walk_measure_sees_a_climb():
    """What the check above relies on: a callback from a lower layer into a higher one is an
    upward call and a climb; a call down is neither."""
    down = Call(("relmap.network.query", "query"), ("relmap.uncertain.algebra", "compound"))
    back = Call(("relmap.network.reduce", "_Reducer.reduce"), ("relmap.app.cli", "<lambda>"))
    assert upward([down, back]) == [back] and climbs([down, back]) == [back]
    hook = Call(("relmap.uncertain.pose", "UncertainPose.x"), ("relmap.uncertain.at", "AT.y"))
    assert not upward([hook]) and climbs([hook], ALGEBRA) == [hook] and switches([hook]) == 1


# -------------------------------------------------------------- losses: one registration point
def test_losses_have_one_registration_point():
    """Every loss of the pose-graph optimizer (a class with ``value`` and ``weight`` methods) is
    defined in ``relmap.network.losses`` and named in its ``LOSSES``, the one table that
    ``parse_loss`` (and so ``relmap solve --loss``) reads; no other module reads that table."""
    from relmap.network import losses

    found = {}
    for module in MODULES:
        for node in ast.walk(tree(module)):
            if isinstance(node, ast.ClassDef):
                methods = {f.name for f in node.body if isinstance(f, ast.FunctionDef)}
                if {"value", "weight"} <= methods and node.name != "Loss":
                    found[node.name] = module
    assert found and set(found.values()) == {"relmap.network.losses"}, found
    assert {cls.__name__ for cls in losses.LOSSES.values()} == set(found)
    for module in MODULES:
        if module != "relmap.network.losses":
            assert "LOSSES" not in MODULES[module].read_text(encoding="utf-8"), module
    assert "parse_loss" in MODULES["relmap.app.cli"].read_text(encoding="utf-8")


# -------------------------------------------------------------- models: one registration point
#: The protocols of relmap.models.base a model subclasses (the extension point of the filter).
MODEL_PROTOCOLS = ("Motion", "RelativeMotion", "Measurement")
#: Where the filter still names a concrete built-in model (the integrator removes an entry when
#: its fix lands; the checks below fail both on a new one and on a listed one that is gone).
KNOWN_MODEL_REACHES: dict[tuple[str, str], str] = {
    ("relmap.filter.ekf", "FullPose"): "correct_pose builds a models.pose.FullPose reading: "
    "let it take the Measurement, or move the convenience up to its callers",
}


def _bases(node: ast.ClassDef) -> set[str]:
    return {b.id if isinstance(b, ast.Name) else getattr(b, "attr", "") for b in node.bases}


def model_classes(sources: dict[str, ast.Module]) -> dict[str, str]:
    """Every class of ``sources`` (module name -> parsed source) that subclasses a protocol of
    :data:`MODEL_PROTOCOLS`, directly or through another such class (bases matched by name,
    to a fixed point): qualified name -> module. The protocols themselves are not listed."""
    classes = [
        (module, node)
        for module, parsed in sources.items()
        for node in ast.walk(parsed)
        if isinstance(node, ast.ClassDef)
    ]
    models: set[str] = set(MODEL_PROTOCOLS)
    found: dict[str, str] = {}
    while True:
        new = {
            f"{module}.{node.name}": module
            for module, node in classes
            if _bases(node) & models and node.name not in MODEL_PROTOCOLS
        }
        if new.keys() <= found.keys():
            return found
        found |= new
        models |= {name.rpartition(".")[2] for name in new}


def model_registration(sources: dict[str, ast.Module], exported: set[str]) -> list[str]:
    """What breaks "a model has one registration point" in ``sources``: a model class defined
    outside ``relmap.models``; a public one there that ``relmap.models`` does not export
    (``exported``: its ``__all__``); and in ``relmap.filter`` any import from
    ``relmap.models`` other than the protocols of ``relmap.models.base`` or any use of a concrete
    model's name (the filter reaches models only through the protocols). Each finding ends
    with the name it is about, after ``: ``."""
    models = model_classes(sources)
    concrete = {name.rpartition(".")[2] for name in models}
    found = [
        f"a model defined outside relmap.models: {name}"
        for name, module in models.items()
        if not module.startswith("relmap.models.")
    ]
    found += [
        f"a model relmap.models does not export: {name}"
        for name, module in models.items()
        if module.startswith("relmap.models.")
        and not name.rpartition(".")[2].startswith("_")
        and name.rpartition(".")[2] not in exported
    ]
    for module, parsed in sources.items():
        if not module.startswith("relmap.filter"):
            continue
        for node in ast.walk(parsed):
            if isinstance(node, ast.ImportFrom) and (node.module or "").startswith("relmap.models"):
                for alias in node.names:
                    if node.module != "relmap.models.base" and alias.name not in MODEL_PROTOCOLS:
                        found.append(f"{module} imports from {node.module}: {alias.name}")
            elif isinstance(node, ast.Import):
                for alias in node.names:
                    name = alias.name
                    if name.startswith("relmap.models.") and name != "relmap.models.base":
                        found.append(f"{module} imports a models module: {alias.name}")
            elif isinstance(node, (ast.Name, ast.Attribute)):
                name = node.id if isinstance(node, ast.Name) else node.attr
                if name in concrete:
                    found.append(f"{module} names the model: {name}")
    return sorted(set(found))


def _model_reaches() -> list[str]:
    import relmap.models

    return model_registration({m: tree(m) for m in LIBRARY}, set(relmap.models.__all__))


def test_models_have_one_registration_point():
    """A model (a subclass of a protocol of :mod:`relmap.models.base`) is defined under
    ``relmap/models/`` and exported from :mod:`relmap.models`, or is a user's (tests,
    examples: outside ``src``); the filter names no built-in model and imports from
    ``relmap.models`` only the protocols of ``relmap.models.base``, so a user's model runs
    through exactly the code the built-in ones do."""
    import importlib

    import relmap.models.base as base

    found = model_classes({m: tree(m) for m in LIBRARY})
    # the AST's view is the interpreter's: every model of relmap.models, no more, no fewer
    for module in [m for m in MODULES if m.startswith("relmap.models.")]:
        importlib.import_module(module)
    todo, live = [base.Motion, base.Measurement], set()
    while todo:
        for cls in todo.pop().__subclasses__():
            todo.append(cls)
            if cls.__module__.startswith("relmap.") and cls.__name__ not in MODEL_PROTOCOLS:
                live.add(f"{cls.__module__}.{cls.__qualname__}")
    assert "relmap.models.range_bearing.RangeBearingSensor" in found  # (not vacuous)
    assert {n for n in found if n.startswith("relmap.models.")} == live
    new = [f for f in _model_reaches() if _reach(f) not in KNOWN_MODEL_REACHES]
    assert not new, f"models with more than one registration point: {new}"


def _reach(finding: str) -> tuple[str, str]:
    return finding.split()[0], finding.rpartition(": ")[2]


def test_the_known_model_reaches_are_still_there():
    """KNOWN_MODEL_REACHES stays true: an entry that is gone is to be removed."""
    gone = [k for k in KNOWN_MODEL_REACHES if k not in map(_reach, _model_reaches())]
    assert not gone, f"fixed; remove them from KNOWN_MODEL_REACHES: {gone}"


def test_the_model_check_finds_a_second_registration_point():
    """What the check above relies on: a model defined outside relmap.models (also through a
    model subclass), one relmap.models does not export, and a filter that imports or names a
    concrete model are each found; the filter's use of the protocols is not."""
    sources = {
        "relmap.models.base": ast.parse("class Model: ...\nclass Measurement(Model): ..."),
        "relmap.models.gps": ast.parse(
            "from relmap.models.base import Measurement\n"
            "class Fix(Measurement): ...\n"
            "class _Polar(Measurement): ...\n"
            "class Hidden(_Polar): ...\n"
            "class Noise: ...\n"
        ),
        "relmap.io.sensors": ast.parse(
            "from relmap.models import base\nclass Lidar(base.Measurement): ..."
        ),
        "relmap.filter.runner": ast.parse(
            "from relmap.models.base import Measurement, Motion\n"
            "from relmap.models.gps import Fix\n"
            "import relmap.models.gps\n"
            "def run(model: Measurement):\n"
            "    return isinstance(model, relmap.models.gps.Hidden) or Fix(1.0)\n"
        ),
    }
    found = model_registration(sources, exported={"Fix", "Measurement"})
    assert found == [
        "a model defined outside relmap.models: relmap.io.sensors.Lidar",
        "a model relmap.models does not export: relmap.models.gps.Hidden",
        "relmap.filter.runner imports a models module: relmap.models.gps",
        "relmap.filter.runner imports from relmap.models.gps: Fix",
        "relmap.filter.runner names the model: Fix",
        "relmap.filter.runner names the model: Hidden",
    ], found
    clean = {k: v for k, v in sources.items() if k.startswith("relmap.models")}
    clean["relmap.filter.runner"] = ast.parse(
        "from relmap.models.base import Measurement\ndef run(m: Measurement): return m.h"
    )
    assert model_registration(clean, exported={"Fix", "Hidden"}) == []


if __name__ == "__main__":  # the counts of the report: python tests/test_architecture.py
    import sys
    import tempfile

    sys.path.insert(0, str(SRC.parent))
    extra = [["query", "--method", "reduce", "{examples}/bridge.yaml", "w", "u"]]
    shared = SRC.parent.parent / "shared" / "data"
    with tempfile.TemporaryDirectory() as folder:
        places = _walk_files(Path(folder), shared if shared.is_dir() else None)
        for argv in [p.values[0] for p in WALKS] + extra:
            if "{mrclam}" in argv and "mrclam" not in places:
                continue
            calls = walk([a.format(**places) for a in argv])
            up = upward(calls)
            print(
                f"relmap {' '.join(argv[:3])}: {len(calls)} calls, {len(up)} up a layer "
                f"({sum(c.callee in CALLBACKS for c in up)} of them CALLBACKS), "
                f"{len(climbs(calls))} against the import graph "
                f"({len(climbs(calls, ALGEBRA))} in the AT algebra), {switches(calls)} switches "
                "between the AT algebra's modules"
            )
