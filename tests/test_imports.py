"""The package's import graph has no circle.

Every module of ``ident``, ``mocap`` and ``calib`` is parsed (not imported) and each
``import``/``from ... import`` of a project module, at module level or inside a function,
becomes an edge; a strongly connected component of more than one module is an import circle.
"""
from __future__ import annotations

import ast
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]
PACKAGES = ("ident", "mocap", "calib")


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
