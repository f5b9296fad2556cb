"""The package's import graph has no circle, and project imports sit at module level.

Every module of ``ident``, ``mocap`` and ``calib`` is parsed (not imported) and each
``import``/``from ... import`` of a project module, at module level or inside a function,
becomes an edge; a strongly connected component of more than one module is an import circle.

A project import inside a function (``ident``, ``mocap``, ``calib``, ``viz`` or relative) is
allowed only where :data:`LOCAL_IMPORT_ALLOWED` names it with its reason: an optional or costly
dependency imported where it is used, or the command line's start-up time.
"""
from __future__ import annotations

import ast
import subprocess
import sys
from fnmatch import fnmatch
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]
PACKAGES = ("ident", "mocap", "calib")
PROJECT = ("ident", "mocap", "calib", "viz")

# (file pattern, imported module pattern): why the import waits until the function runs.
LOCAL_IMPORT_ALLOWED = {
    # CLI start-up: ident.cli.main.build_parser imports every command module to register its
    # subcommand, so `jointlab --help` would load the whole package if a command imported its
    # work at module level; each command imports what it runs inside run().
    ("ident/cli/commands/*.py", "*"): "CLI start-up time (`jointlab --help`)",
    # optional/costly dependency: viz.rerun_sink imports rerun (and viz.sink, which it extends);
    # the null sink of a run without --rrd/--spawn never loads rerun.
    ("viz/sink.py", "viz.rerun_sink"): "optional dependency: rerun",
    # costly dependency: viz.plots imports matplotlib, needed only when figures are written.
    ("ident/coastdown/campaign_analysis.py", "viz.plots"): "import cost: matplotlib (figures only)",
    # optional dependency: the MuJoCo nominal (--nominal mjcf:PATH) reads the model through
    # ident.sim2real.model, which imports mujoco (the [mujoco] extra)
    ("ident/gap/nominal.py", "ident.sim2real.model"): "optional dependency: mujoco",
}



def _modules() -> dict:
    """{dotted module name: path} of the project's packages."""
    out = {}
    for pkg in PACKAGES:
        for p in (ROOT / pkg).rglob("*.py"):
            parts = p.relative_to(ROOT).with_suffix("").parts
            if parts[-1] == "__init__":
                parts = parts[:-1]
            out[".".join(parts)] = p
    return out


def _resolve(name: str, mods: dict):
    """The project module an imported dotted name refers to (the longest known prefix)."""
    parts = name.split(".")
    for k in range(len(parts), 0, -1):
        cand = ".".join(parts[:k])
        if cand in mods:
            return cand
    return None


def import_graph(mods: dict | None = None) -> dict:
    """{module: set of project modules it imports} (``from pkg import sub`` counts ``pkg.sub``
    when ``sub`` is a module, else ``pkg``)."""
    mods = _modules() if mods is None else mods
    graph = {}
    for name, path in mods.items():
        is_pkg = path.name == "__init__.py"
        deps = set()
        for node in ast.walk(ast.parse(path.read_text(), str(path))):
            if isinstance(node, ast.Import):
                targets = [a.name for a in node.names]
            elif isinstance(node, ast.ImportFrom):
                if node.level:
                    base = name.split(".")
                    base = base[:len(base) - node.level + (1 if is_pkg else 0)]
                    mod = ".".join(base + ([node.module] if node.module else []))
                else:
                    mod = node.module or ""
                targets = [f"{mod}.{a.name}" if f"{mod}.{a.name}" in mods else mod
                           for a in node.names]
            else:
                continue
            for t in targets:
                r = _resolve(t, mods)
                if r is not None and r != name:
                    deps.add(r)
        graph[name] = deps
    return graph


def cycles(graph: dict) -> list:
    """The strongly connected components of more than one module (Tarjan, iterative)."""
    index, low, on, stack, out = {}, {}, set(), [], []
    counter = [0]
    for root in graph:
        if root in index:
            continue
        work = [(root, iter(sorted(graph[root])))]
        index[root] = low[root] = counter[0]
        counter[0] += 1
        stack.append(root)
        on.add(root)
        while work:
            v, it = work[-1]
            for w in it:
                if w not in index:
                    index[w] = low[w] = counter[0]
                    counter[0] += 1
                    stack.append(w)
                    on.add(w)
                    work.append((w, iter(sorted(graph.get(w, ())))))
                    break
                if w in on:
                    low[v] = min(low[v], index[w])
            else:
                work.pop()
                if work:
                    low[work[-1][0]] = min(low[work[-1][0]], low[v])
                if low[v] == index[v]:
                    comp = set()
                    while True:
                        w = stack.pop()
                        on.discard(w)
                        comp.add(w)
                        if w == v:
                            break
                    if len(comp) > 1:
                        out.append(frozenset(comp))
    return out


def test_cycle_finder_finds_a_planted_circle():
    g = {"a": {"b"}, "b": {"c"}, "c": {"a"}, "d": {"a"}, "e": set()}
    assert cycles(g) == [frozenset({"a", "b", "c"})]
    assert cycles({"a": {"b"}, "b": set()}) == []


def test_graph_sees_function_local_and_relative_imports(tmp_path):
    mods = {"p": tmp_path / "p" / "__init__.py", "p.x": tmp_path / "p" / "x.py",
            "p.y": tmp_path / "p" / "y.py"}
    for f in mods.values():
        f.parent.mkdir(exist_ok=True)
    mods["p"].write_text("")
    mods["p.x"].write_text("def f():\n    from p import y\n")
    mods["p.y"].write_text("from .x import f\n")
    g = import_graph(mods)
    assert g["p.x"] == {"p.y"} and g["p.y"] == {"p.x"}
    assert cycles(g) == [frozenset({"p.x", "p.y"})]


def test_no_import_circle():
    assert cycles(import_graph()) == []


def local_project_imports(root: Path = ROOT, packages=PROJECT) -> list:
    """``(file relative to root, line, imported module)`` of every import of a project module
    (relative imports included) that sits inside a function, in ``packages``."""
    out = []
    for pkg in packages:
        for path in sorted((root / pkg).rglob("*.py")):
            rel = path.relative_to(root).as_posix()
            stack = [(n, False) for n in ast.parse(path.read_text(), str(path)).body]
            while stack:
                node, in_func = stack.pop()
                if in_func and isinstance(node, (ast.Import, ast.ImportFrom)):
                    if isinstance(node, ast.ImportFrom):
                        mods = ["." * node.level + (node.module or "")]
                    else:
                        mods = [a.name for a in node.names]
                    for m in mods:
                        if m.startswith(".") or m.split(".")[0] in PROJECT:
                            out.append((rel, node.lineno, m))
                inner = in_func or isinstance(node, (ast.FunctionDef, ast.AsyncFunctionDef, ast.Lambda))
                stack.extend((c, inner) for c in ast.iter_child_nodes(node))
    return sorted(out)


def _allowed(rel: str, mod: str) -> bool:
    return any(fnmatch(rel, f) and fnmatch(mod, m) for f, m in LOCAL_IMPORT_ALLOWED)


def test_local_import_finder_sees_nested_and_relative_imports(tmp_path):
    (tmp_path / "ident" / "sub").mkdir(parents=True)
    (tmp_path / "ident" / "sub" / "m.py").write_text(
        "import numpy\nfrom ident.a import b\n\n"
        "def f():\n    import json\n    from mocap.io import errors\n\n"
        "class C:\n    def g(self):\n        if True:\n            from . import x\n"
        "        def h():\n            import viz.sink\n")
    found = local_project_imports(tmp_path, ("ident",))
    assert found == [("ident/sub/m.py", 6, "mocap.io"), ("ident/sub/m.py", 11, "."),
                     ("ident/sub/m.py", 13, "viz.sink")]
    assert _allowed("ident/cli/commands/fit.py", "mocap.io.campaign")
    assert not _allowed("ident/cli/main.py", "ident.outputs")


def test_project_imports_at_module_level():
    """Function-local project imports only where LOCAL_IMPORT_ALLOWED says why."""
    bad = [f"{rel}:{line}: {mod}" for rel, line, mod in local_project_imports()
           if not _allowed(rel, mod)]
    assert not bad, "function-local project imports (move them to module level):\n" + "\n".join(bad)


def test_allowlist_entries_are_used():
    """Every allowlist entry still matches an import (a stale entry would allow a future one)."""
    found = local_project_imports()
    unused = [k for k in LOCAL_IMPORT_ALLOWED
              if not any(fnmatch(rel, k[0]) and fnmatch(mod, k[1]) for rel, _, mod in found)]
    assert not unused


def test_cli_start_up_loads_no_heavy_dependency():
    """The reason for the command modules' allowlist entry: building ``jointlab``'s parser (what
    ``jointlab --help`` does) imports none of the heavy dependencies."""
    heavy = ("scipy", "matplotlib", "rerun", "pinocchio", "trimesh", "cv2", "pyarrow", "ezc3d")
    code = ("import sys; from ident.cli.main import build_parser; build_parser(); "
            f"print(sorted(m for m in {heavy!r} if m in sys.modules))")
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, check=True,
                         cwd=ROOT)
    assert out.stdout.strip() == "[]", out.stdout


# a private (underscore) name taken from another package, still to be made public by the owner
# of the module that defines it: (importing file, module, name) -> why it waits (none left)
PRIVATE_IMPORT_PENDING: dict = {}


def test_no_package_imports_another_packages_private_names():
    """``from a.b.m import _x`` only within the package ``a.b`` (issue 44)."""
    bad = []
    for name, path in _modules().items():
        pkg = name if path.name == "__init__.py" else name.rsplit(".", 1)[0]
        for node in ast.walk(ast.parse(path.read_text(), str(path))):
            if not (isinstance(node, ast.ImportFrom) and node.module and not node.level):
                continue
            if node.module.split(".")[0] not in PROJECT or node.module.rsplit(".", 1)[0] == pkg:
                continue
            for a in node.names:
                rel = path.relative_to(ROOT).as_posix()
                if (a.name.startswith("_") and not a.name.startswith("__")
                        and (rel, node.module, a.name) not in PRIVATE_IMPORT_PENDING):
                    bad.append(f"{rel}:{node.lineno}: from {node.module} import {a.name}")
    assert not bad, "\n".join(bad)


def test_no_argparse_namespace_outside_the_cli():
    """No function outside ``ident/cli`` takes the command line's ``args``: the CLI maps them to
    values or settings once (issue 44)."""
    bad = []
    for name, path in _modules().items():
        if name.startswith("ident.cli"):
            continue
        for node in ast.walk(ast.parse(path.read_text(), str(path))):
            if isinstance(node, (ast.FunctionDef, ast.AsyncFunctionDef)):
                if any(a.arg == "args" for a in node.args.args + node.args.kwonlyargs):
                    bad.append(f"{path.relative_to(ROOT).as_posix()}:{node.lineno}: {node.name}(args)")
    assert not bad, "\n".join(bad)
