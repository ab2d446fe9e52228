"""nodes/ holds the executables only, as thin wiring: no threads, locks, sleeps, module-level
state or ``getattr`` on other objects (the host in ros/ owns threads and timing and runs a
node's callbacks one at a time with its hot loop); every other module there serves one
executable and is named after it. Read from the source (:mod:`ast`)."""

from __future__ import annotations

import ast
from collections.abc import Iterator

from test_structure import MODULES, ROOT, _part

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
NODE_EXCEPTIONS: dict[str, str] = {}
#: Names that are locks, or calls that take, free or test one (the host serializes a node's
#: callbacks with its hot loop: ros/serialized.py).
_LOCK_CALLS = ("acquire", "release", "locked")


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


def _breaks_in(tree: ast.Module) -> list[tuple[str, int, str]]:
    """(rule, line, what) for every break of the node-file rules in one module."""
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
            if name in ("Thread", "Semaphore", "Condition"):
                found.append(("threads", node.lineno, name))
            elif name in ("Lock", "RLock", "lock") or name.endswith("_lock"):
                found.append(("locks", node.lineno, ast.unparse(node)))
        if isinstance(node, ast.Call):
            call = ast.unparse(node.func)
            if isinstance(node.func, ast.Attribute) and node.func.attr in _LOCK_CALLS:
                found.append(("locks", node.lineno, ast.unparse(node)))
            if call in ("time.sleep", "sleep"):
                found.append(("sleep", node.lineno, ast.unparse(node)))
            elif call in ("getattr", "hasattr", "setattr") and not (
                    node.args and isinstance(node.args[0], ast.Call)
                    and ast.unparse(node.args[0].func) == _BY_NAME):
                found.append(("getattr", node.lineno, ast.unparse(node)))
    return found


def _node_breaks() -> dict[str, list[str]]:
    """``module:rule`` -> ``line: what`` for every break of the node-file rules."""
    out: dict[str, list[str]] = {}
    for module, path in MODULES.items():
        if _part(module) != "nodes" or path.name == "__init__.py":
            continue
        for rule, line, what in _breaks_in(ast.parse(path.read_text(), str(path))):
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
    timing, and runs a node's callbacks one at a time with its hot loop), no module-level
    mutable state and no ``getattr``/``hasattr`` on other objects
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


def test_node_rules_see_every_kind_of_lock() -> None:
    """Each way a node could lock is found: a lock object, ``.lock``, ``*_lock``, acquire."""
    code = ("from threading import RLock\nclass N:\n    def f(self):\n"
            "        with self.hot.lock:\n            pass\n"
            "        self._switch_lock.acquire(blocking=False)\n        return RLock()\n")
    found = sorted((line, what) for rule, line, what in _breaks_in(ast.parse(code))
                   if rule == "locks")
    assert found == [(4, "self.hot.lock"), (6, "self._switch_lock"),
                     (6, "self._switch_lock.acquire(blocking=False)"), (7, "RLock")], found
