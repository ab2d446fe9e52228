"""The package's structure: no import cycles, the layers, every module importable on its own.

The import graph is read from the source (:mod:`ast`): every ``import`` of a ``dcsms_ros``
module counts, at module level, under ``if TYPE_CHECKING:`` or inside a function, so a
function-local import cannot hide a cycle.
"""

from __future__ import annotations

import ast
import importlib.util
import json
import subprocess
import sys
from collections.abc import Iterator
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
PACKAGE = ROOT / "dcsms_ros"

#: What each part of the package may import from the others (cli: anything). A part is a
#: sub-package or a top-level module; ``dcsms_ros`` is the package's ``__init__``.
ALLOWED: dict[str, set[str]] = {
    "errors": set(),
    "jsonutil": set(),
    "rosenv": set(),
    "markers": {"errors"},
    "cdr": {"errors"},
    "core": {"errors"},
    "protocols": {"core", "errors"},
    "analysis": {"core", "errors", "jsonutil", "cdr"},
    "design": {"core", "analysis", "errors"},
    "graph": {"core", "errors"},
    "ros": {"core", "protocols", "graph", "errors", "jsonutil", "cdr", "rosenv"},
    "nodes": {"ros", "core", "analysis", "protocols", "graph", "errors", "jsonutil", "cdr",
              "rosenv"},
}
#: Parts that never import ROS (rclpy, message packages), not even inside a function.
ROS_FREE = set(ALLOWED) - {"nodes", "ros"}
#: Top-level names of the ROS Python packages this project uses.
ROS_PACKAGES = ("rclpy", "builtin_interfaces", "diagnostic_msgs", "geometry_msgs",
                "sensor_msgs", "std_msgs", "std_srvs", "rosgraph_msgs", "rcl_interfaces")


def _modules() -> dict[str, Path]:
    out = {}
    for p in sorted(PACKAGE.rglob("*.py")):
        parts = list(p.relative_to(ROOT).with_suffix("").parts)
        if parts[-1] == "__init__":
            parts = parts[:-1]
        out[".".join(parts)] = p
    return out


MODULES = _modules()


def _part(module: str) -> str:
    parts = module.split(".")
    return parts[1] if len(parts) > 1 else "dcsms_ros"


def _imports(module: str) -> Iterator[tuple[str, int]]:
    """(imported name, line) of every import statement in ``module``, wherever it stands;
    ``from a import b`` yields ``a.b`` (a module or a name in ``a``)."""
    path = MODULES[module]
    for node in ast.walk(ast.parse(path.read_text(), str(path))):
        if isinstance(node, ast.Import):
            for a in node.names:
                yield a.name, node.lineno
        elif isinstance(node, ast.ImportFrom):
            base = node.module or ""
            if node.level:
                here = module.split(".")
                if path.name != "__init__.py":
                    here = here[:-1]
                here = here[:len(here) - (node.level - 1)]
                base = ".".join([*here, base] if base else here)
            for a in node.names:
                yield f"{base}.{a.name}", node.lineno


def _resolve(name: str) -> str | None:
    """The package module ``name`` refers to (the longest prefix that is a module)."""
    while name and name not in MODULES:
        name = name.rpartition(".")[0]
    return name or None


def _graph() -> dict[str, dict[str, int]]:
    """module -> {imported package module: line of the first import}."""
    graph: dict[str, dict[str, int]] = {}
    for m in MODULES:
        edges: dict[str, int] = {}
        for name, line in _imports(m):
            if name == "dcsms_ros" or name.startswith("dcsms_ros."):
                target = _resolve(name)
                if target is not None and target != m:
                    edges.setdefault(target, line)
        graph[m] = edges
    return graph


def _cycles(graph: dict[str, dict[str, int]]) -> list[list[str]]:
    """Strongly connected components with more than one module (Tarjan)."""
    index: dict[str, int] = {}
    low: dict[str, int] = {}
    stack: list[str] = []
    on: set[str] = set()
    out: list[list[str]] = []

    def visit(v: str) -> None:
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
            comp = []
            while True:
                w = stack.pop()
                on.discard(w)
                comp.append(w)
                if w == v:
                    break
            if len(comp) > 1:
                out.append(sorted(comp))

    for v in graph:
        if v not in index:
            visit(v)
    return out


def test_the_graph_reader_sees_every_kind_of_import() -> None:
    """The reader finds module-level, relative, TYPE_CHECKING and function-local imports (so a
    cycle through any of them is found)."""
    assert "dcsms_ros.core.config" in _graph()["dcsms_ros.core.model"]
    tree = {"a": {"b": 1}, "b": {"c": 1}, "c": {"a": 1}, "d": {"a": 1}}
    assert _cycles(tree) == [["a", "b", "c"]]
    code = ("from typing import TYPE_CHECKING\nif TYPE_CHECKING:\n    from . import errors\n"
            "def f():\n    from .core import modes\n")
    names = {n for node in ast.walk(ast.parse(code)) if isinstance(node, ast.ImportFrom)
             for n in (a.name for a in node.names)}
    assert names == {"TYPE_CHECKING", "errors", "modes"}


def test_no_import_cycles() -> None:
    """The package's import graph (function-local imports included) has no cycle."""
    graph = _graph()
    msgs = []
    for comp in _cycles(graph):
        edges = [f"{a} -> {b} (line {graph[a][b]})" for a in comp for b in graph[a] if b in comp]
        msgs.append("cycle: " + "; ".join(edges))
    assert not msgs, "\n".join(msgs)


def test_no_module_reads_another_objects_private_attributes() -> None:
    """``x._name`` only on ``self``/``cls``: the fast engine (and everything else) goes through
    the step objects' documented API, so changing an object's internals cannot silently break
    a reader elsewhere."""
    found = [f"{module}:{node.lineno}: {ast.unparse(node)}"
             for module, path in MODULES.items()
             for node in ast.walk(ast.parse(path.read_text(), str(path)))
             if isinstance(node, ast.Attribute) and node.attr.startswith("_")
             and not node.attr.startswith("__")
             and not (isinstance(node.value, ast.Name) and node.value.id in ("self", "cls"))]
    assert not found, "private attributes read from outside: " + ", ".join(found)


def test_layers() -> None:
    """Each part imports only the parts below it; core, analysis, design, protocols and the
    graph definition never import ROS, not even inside a function."""
    bad = []
    for m in MODULES:
        part = _part(m)
        for name, line in _imports(m):
            where = f"{MODULES[m].relative_to(ROOT)}:{line}"
            top = name.split(".")[0]
            if top == "dcsms_ros":
                target = _resolve(name)
                other = _part(target) if target else "dcsms_ros"
                if part in ALLOWED and other != part and other not in ALLOWED[part] | {
                        "dcsms_ros"}:
                    bad.append(f"{where}: {part} imports {name} ({other})")
            elif part in ROS_FREE and top in ROS_PACKAGES:
                bad.append(f"{where}: {part} imports ROS ({name})")
    assert not bad, "\n".join(bad)


_ALONE = r"""
import importlib, json, sys
out = {}
for name, ros_free in json.loads(sys.stdin.read()):
    for k in [k for k in sys.modules if k == "dcsms_ros" or k.startswith("dcsms_ros.")]:
        del sys.modules[k]
    try:
        importlib.import_module(name)
    except Exception as exc:
        out[name] = f"{type(exc).__name__}: {exc}"
        continue
    if ros_free and "rclpy" in sys.modules:
        out[name] = "imports rclpy"
print(json.dumps(out))
"""


def test_every_module_imports_on_its_own() -> None:
    """Each module imported first (no other module of the package loaded before it) works;
    the ROS-free ones (imported first, before anything loads rclpy) do not pull in rclpy."""
    order = sorted(MODULES, key=lambda m: (_part(m) not in ROS_FREE, m))
    # the compiled loop needs the optional numba (core.fastsim imports it only when present)
    numba = importlib.util.find_spec("numba") is not None
    todo = [(m, _part(m) in ROS_FREE) for m in order
            if not m.endswith(".__main__")  # runs the program
            and (m != "dcsms_ros.core.fastloop" or numba)]
    res = subprocess.run([sys.executable, "-c", _ALONE], input=json.dumps(todo), cwd=ROOT,
                         capture_output=True, text=True, timeout=300, check=False)
    assert res.returncode == 0, res.stderr[-3000:]
    failed = json.loads(res.stdout.strip().splitlines()[-1])
    assert not failed, "\n".join(f"{k}: {v}" for k, v in failed.items())


def test_dcsms_help_does_not_import_ros() -> None:
    """Building the ``dcsms`` parser (what ``dcsms --help`` does) imports no ROS package: the
    sub-commands import rclpy when they run."""
    code = ("import sys, dcsms_ros.cli; dcsms_ros.cli.build_parser(); "
            f"print(sorted(m for m in sys.modules if m.split('.')[0] in {ROS_PACKAGES!r}))")
    res = subprocess.run([sys.executable, "-c", code], cwd=ROOT, capture_output=True,
                         text=True, timeout=120, check=False)
    assert res.returncode == 0, res.stderr[-3000:]
    assert res.stdout.strip() == "[]", res.stdout


def _numba() -> bool:
    import importlib.util

    return importlib.util.find_spec("numba") is not None


def test_architecture_page_lists_every_module() -> None:
    """docs/ARCHITECTURE.md names every module, each in its part's section (subpackage
    ``__init__`` files excepted)."""
    text = (ROOT / "docs" / "ARCHITECTURE.md").read_text()
    sections = {}
    for block in text.split("\n### ")[1:]:
        heading, _, body = block.partition("\n")
        sections[heading] = body
    missing = []
    for path in MODULES.values():
        rel = path.relative_to(PACKAGE)
        if len(rel.parts) == 1:
            if f"`{rel.name}`" not in text:
                missing.append(str(rel))
            continue
        if rel.name == "__init__.py":
            continue
        part = rel.parts[0] + "/"
        body = "".join(b for h, b in sections.items() if part in h)
        if f"{rel.name}`" not in body:
            missing.append(str(rel))
    assert not missing, "not in docs/ARCHITECTURE.md: " + ", ".join(missing)


# -- nodes/: the executables only ------------------------------------------------------------
#: Executables of nodes/ (setup.py's NODES, ``ros2 run dcsms_ros <name>``) and the composed
#: graph's ``python -m dcsms_ros.nodes.container``: every other module in nodes/ serves one
#: of them and is named after it (``plant_simulator_io.py``).
#: Module-level names a node file may bind besides constants (UPPER_CASE) and ``__all__``.
_NODE_NAMES_OK = {"main", "__all__"}
#: Calls that read an attribute by name from a module (a class or message type named in a
#: graph file or a topic's type), not from another object.
_BY_NAME = "importlib.import_module"
#: Rule breaks in nodes/ still to be removed, each with why it is still there: a new break
#: fails the test, and so does an entry here that no longer breaks (take it out).
NODE_EXCEPTIONS: dict[str, str] = {
    "dcsms_ros.nodes.mode_switch:threads":
        "_switch_lock serialises a user's switch, a trip and the supervisor's switch, which "
        "run on executor threads and on the hot thread (lockstep trip: the controllers are "
        "disabled before the plant hears the verdict, so the switch must block there)",
    "dcsms_ros.nodes.recorder:threads":
        "composed, the bag is written by the executor (topics from other processes) and by the "
        "driver thread (in-process delivery, ros/intraprocess.py); one lock orders the writes",
}


def _setup_nodes() -> set[str]:
    tree = ast.parse((ROOT / "setup.py").read_text())
    for node in tree.body:
        if isinstance(node, ast.Assign) and any(
                isinstance(t, ast.Name) and t.id == "NODES" for t in node.targets):
            return set(ast.literal_eval(node.value))
    raise AssertionError("setup.py has no NODES")


def _is_constant(value: ast.expr) -> bool:
    """A literal, a tuple or frozenset of literals, or arithmetic on them (immutable)."""
    if isinstance(value, ast.Constant):
        return True
    if isinstance(value, ast.Tuple):
        return all(_is_constant(e) for e in value.elts)
    if isinstance(value, ast.BinOp):
        return _is_constant(value.left) and _is_constant(value.right)
    if isinstance(value, ast.UnaryOp):
        return _is_constant(value.operand)
    if isinstance(value, ast.Call) and isinstance(value.func, ast.Name) and \
            value.func.id == "frozenset":
        return all(_is_constant(a) or (isinstance(a, ast.Set) and all(
            _is_constant(e) for e in a.elts)) for a in value.args)
    return False


def _module_state(tree: ast.Module) -> Iterator[tuple[int, str]]:
    """Module-level bindings that are not constants, ``__all__`` or ``main``; ``global``."""
    for node in tree.body:
        targets: list[ast.expr] = []
        value: ast.expr | None = None
        if isinstance(node, ast.Assign):
            targets, value = node.targets, node.value
        elif isinstance(node, ast.AnnAssign):
            if isinstance(node.annotation, ast.Name) and node.annotation.id == "TypeAlias":
                continue
            targets, value = [node.target], node.value
        elif isinstance(node, ast.AugAssign):
            targets = [node.target]
        for t in targets:
            name = t.id if isinstance(t, ast.Name) else ast.unparse(t)
            if name in _NODE_NAMES_OK:
                continue
            constant = name.lstrip("_").isupper() and value is not None and _is_constant(value)
            if not constant:
                yield node.lineno, f"module-level {name}"
    for node in ast.walk(tree):
        if isinstance(node, ast.Global):
            yield node.lineno, f"global {', '.join(node.names)}"


def _node_breaks() -> dict[str, list[str]]:
    """``module:rule`` -> ``line: what`` for every break of the node-file rules."""
    out: dict[str, list[str]] = {}
    for module, path in MODULES.items():
        if _part(module) != "nodes" or path.name == "__init__.py":
            continue
        tree = ast.parse(path.read_text(), str(path))
        found: list[tuple[str, int, str]] = [("state", line, what)
                                             for line, what in _module_state(tree)]
        for node in ast.walk(tree):
            if isinstance(node, ast.Import | ast.ImportFrom):
                names = [a.name for a in node.names] if isinstance(node, ast.Import) else [
                    node.module or ""]
                if "threading" in names or "_thread" in names:
                    found.append(("threads", node.lineno, "imports threading"))
            elif isinstance(node, ast.Attribute | ast.Name):
                name = node.attr if isinstance(node, ast.Attribute) else node.id
                if name in ("Lock", "RLock", "Thread", "Semaphore", "Condition"):
                    found.append(("threads", node.lineno, name))
            if isinstance(node, ast.Call):
                call = ast.unparse(node.func)
                if call in ("time.sleep", "sleep"):
                    found.append(("sleep", node.lineno, ast.unparse(node)))
                elif call in ("getattr", "hasattr", "setattr") and not (
                        node.args and isinstance(node.args[0], ast.Call)
                        and ast.unparse(node.args[0].func) == _BY_NAME):
                    found.append(("getattr", node.lineno, ast.unparse(node)))
        for rule, line, what in found:
            out.setdefault(f"{module}:{rule}", []).append(f"{line}: {what}")
    return out


def test_node_modules_are_executables_or_named_after_one() -> None:
    """Each module of nodes/ is an executable (a module-level ``main``, ``ros2 run`` names it
    in setup.py or it is the composed graph's) or serves one executable and is named after it
    (``plant_simulator_io.py``); shared infrastructure lives in ros/."""
    exes = _setup_nodes() | {"container"}
    bad = []
    for module, path in MODULES.items():
        if _part(module) != "nodes" or path.name == "__init__.py":
            continue
        stem = path.stem
        tree = ast.parse(path.read_text(), str(path))
        has_main = any((isinstance(n, ast.FunctionDef) and n.name == "main") or (isinstance(
            n, ast.Assign) and any(isinstance(t, ast.Name) and t.id == "main" for t in n.targets))
            for n in tree.body)
        if stem in exes and has_main:
            continue
        if stem not in exes and any(stem.startswith(f"{e}_") for e in exes):
            continue
        bad.append(f"{path.relative_to(ROOT)}" + (" has no main()" if stem in exes else
                                                 " is neither an executable nor named after one"))
    assert not bad, "\n".join(bad)
    assert {p.stem for m, p in MODULES.items() if _part(m) == "nodes"} >= exes


def test_node_files_are_wiring_only() -> None:
    """Files in nodes/ hold no threads, locks or sleeps (the host in ros/ owns threads and
    timing), no module-level mutable state and no ``getattr``/``hasattr`` on other objects
    (a class or message type may be looked up by name in a module); the known exceptions are
    listed, with why, in :data:`NODE_EXCEPTIONS`."""
    breaks = _node_breaks()
    new = {k: v for k, v in breaks.items() if k not in NODE_EXCEPTIONS}
    stale = sorted(set(NODE_EXCEPTIONS) - set(breaks))
    assert not new, "\n".join(f"{k}: {'; '.join(v)}" for k, v in new.items())
    assert not stale, f"no longer broken, take out of NODE_EXCEPTIONS: {stale}"


def test_node_rules_see_every_kind_of_break() -> None:
    """The rule reader finds each kind of break (so an empty result means something)."""
    code = ("import threading\nimport time\nCACHE = {}\nLIMIT = 2 ** 3\nmain = f\n"
            "def g(x):\n    global CACHE\n    time.sleep(1)\n    threading.Lock()\n"
            "    getattr(x, 'y')\n    getattr(importlib.import_module('m'), 'C')\n")
    tree = ast.parse(code)
    assert [w for _, w in _module_state(tree)] == ["module-level CACHE", "global CACHE"]
    calls = [ast.unparse(n.func) for n in ast.walk(tree) if isinstance(n, ast.Call)]
    assert "time.sleep" in calls and "getattr" in calls


def test_decisions_do_not_read_diagnostics() -> None:
    """Only the status display of ``dcsms up`` (cli/monitor.py) subscribes to
    ``/diagnostics``: what a node or the supervisor decides on travels on named, typed topics
    and services (mode, supervisor/state, plant/held, plant/finished, <controller>/boot)."""
    readers = [module for module, path in MODULES.items()
               for node in ast.walk(ast.parse(path.read_text(), str(path)))
               if isinstance(node, ast.Call)
               and ast.unparse(node.func).endswith("create_subscription")
               and node.args and ast.unparse(node.args[0]) == "DiagnosticArray"]
    assert readers == ["dcsms_ros.cli.monitor"], readers
