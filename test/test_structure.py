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
    "stopsignals": set(),
    "markers": {"errors"},
    "cdr": {"errors"},
    "core": {"errors"},
    "protocols": {"core", "errors"},
    "analysis": {"core", "errors", "jsonutil", "cdr"},
    "design": {"core", "analysis", "errors"},
    "graph": {"core", "errors"},
    "ros": {"core", "protocols", "graph", "errors", "jsonutil", "cdr", "rosenv", "stopsignals"},
    "nodes": {"ros", "core", "analysis", "protocols", "graph", "errors", "jsonutil", "cdr",
              "rosenv", "stopsignals"},
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
    """``x._name`` only on ``self``/``cls``/``super()``: the fast engine (and everything else)
    goes through the step objects' documented API, so changing an object's internals cannot
    silently break a reader elsewhere."""
    found = [f"{module}:{node.lineno}: {ast.unparse(node)}"
             for module, path in MODULES.items()
             for node in ast.walk(ast.parse(path.read_text(), str(path)))
             if isinstance(node, ast.Attribute) and node.attr.startswith("_")
             and not node.attr.startswith("__")
             and not (isinstance(node.value, ast.Name) and node.value.id in ("self", "cls"))
             and not (isinstance(node.value, ast.Call) and isinstance(node.value.func, ast.Name)
                      and node.value.func.id == "super")]
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


#: Analysis libraries a node process must not import: ~0.8 s of CPU each at start-up
#: (:mod:`dcsms_ros.core.filterdesign` designs the filters the nodes run on numpy).
NODE_FREE = ("control", "scipy.signal", "matplotlib")


def test_dcsms_help_imports_no_ros_and_no_analysis_library() -> None:
    """Building the ``dcsms`` parser (what every ``dcsms`` command does first) imports no ROS
    package and none of :data:`NODE_FREE`: the sub-commands import them when they run. Two
    module-level imports of the Table-4 prediction put scipy.signal (0.8 s) in front of every
    command, `dcsms up` and `dcsms mode` included, until the sixteenth session."""
    code = ("import sys, dcsms_ros.cli; dcsms_ros.cli.build_parser(); "
            f"print(sorted(m for m in sys.modules if m.split('.')[0] in {ROS_PACKAGES!r} "
            f"or m in {NODE_FREE!r}))")
    res = subprocess.run([sys.executable, "-c", code], cwd=ROOT, capture_output=True,
                         text=True, timeout=120, check=False)
    assert res.returncode == 0, res.stderr[-3000:]
    assert res.stdout.strip() == "[]", res.stdout

def test_dcsms_sim_imports_no_scipy_signal() -> None:
    """The batch engine and `dcsms sim`'s bag streaming import no scipy.signal: the engine's
    fast path filters with numba, and scipy's block filter (the object path's) is imported
    when that path is built. At module level it took 0.65 s of every `dcsms sim` (a 1 s run:
    1.0 s wall against 1.7-2.1 s, forty-seventh session)."""
    code = ("import sys, dcsms_ros.core.engine, dcsms_ros.analysis.stream, dcsms_ros.cli.sim; "
            "print('scipy.signal' in sys.modules)")
    res = subprocess.run([sys.executable, "-c", code], cwd=ROOT, capture_output=True,
                         text=True, timeout=120, check=False)
    assert res.returncode == 0, res.stderr[-3000:]
    assert res.stdout.strip() == "False", res.stdout


_NODE_IMPORTS = """
import importlib, json, sys
out = {}
for name in json.loads(sys.stdin.read()):
    importlib.import_module(name)
    bad = [m for m in HEAVY if m in sys.modules]
    if bad:
        out[name] = bad
        break
print(json.dumps(out))
"""


def test_node_modules_import_no_analysis_library() -> None:
    """Importing every module of nodes/, ros/ and protocols/ (in one fresh process, one after
    the other) loads neither python-control, scipy.signal nor matplotlib; the first module
    that does is named."""
    todo = [m for m in MODULES if _part(m) in ("nodes", "ros", "protocols")
            and not m.endswith(".__main__")]
    assert any(m.startswith("dcsms_ros.nodes.plant") for m in todo)
    code = f"HEAVY = {NODE_FREE!r}\n" + _NODE_IMPORTS
    res = subprocess.run([sys.executable, "-c", code], input=json.dumps(todo), cwd=ROOT,
                         capture_output=True, text=True, timeout=300, check=False)
    assert res.returncode == 0, res.stderr[-3000:]
    assert json.loads(res.stdout.strip().splitlines()[-1]) == {}


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


def test_the_host_asks_nodes_by_contract_not_by_getattr() -> None:
    """The host (``ros/``, the composed container) learns a node's hot path, end and final
    reports from :class:`dcsms_ros.ros.hosted.Hosted`, never by ``getattr(node, ...)`` (the
    rule reader is checked on a sample line)."""
    def node_getattrs(text: str) -> list[str]:
        return [ast.unparse(n) for n in ast.walk(ast.parse(text))
                if isinstance(n, ast.Call) and ast.unparse(n.func) == "getattr"
                and n.args and "node" in ast.unparse(n.args[0]).lower()]

    assert node_getattrs("x = getattr(node, 'hot', None)")
    found = {module: calls for module, path in MODULES.items()
             if module.startswith(("dcsms_ros.ros.", "dcsms_ros.nodes.container"))
             and (calls := node_getattrs(path.read_text()))}
    assert not found, found
