"""No function in ``ident/study``, ``ident/gap``, ``calib/`` or ``mocap/solve.py`` runs over 80 lines
of code (issue 44, item 5).

A function's length is its lines from ``def`` to its last line (``ast``: ``end_lineno - lineno
+ 1``) less its docstring: the numpydoc docstrings of the public entry points (``place_base``'s
is 70 lines) are documentation a reader does not have to walk, and counting them would push
their text out rather than split the code. Each longer function is to be split into named steps
that take their inputs as arguments; :data:`ALLOWED` may name one only where it is a single
equation, with why.
"""
from __future__ import annotations

import ast
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
#: the files the rule covers, relative to the repository root (folders: every ``*.py`` below)
SCOPE = ("ident/study", "ident/gap", "calib", "mocap/solve.py")
MAX_LINES = 80
#: "file:qualified name" -> why this function may stay longer (one equation only); none now
ALLOWED: dict = {}


def _docstring_lines(node) -> int:
    body = node.body
    if body and isinstance(body[0], ast.Expr) and isinstance(body[0].value, ast.Constant) \
            and isinstance(body[0].value.value, str):
        return body[0].end_lineno - body[0].lineno + 1
    return 0


def long_functions(root: Path = ROOT, scope=SCOPE, limit: int = MAX_LINES) -> list:
    """``(file, qualified name, code lines)`` of every function (methods and nested functions
    included) longer than ``limit`` lines without its docstring, in the files of ``scope``."""
    files = []
    for item in scope:
        path = root / item
        files += sorted(path.rglob("*.py")) if path.is_dir() else [path]
    out = []
    for path in files:
        rel = path.relative_to(root).as_posix()
        todo = [(n, "") for n in ast.parse(path.read_text(), str(path)).body]
        while todo:
            node, prefix = todo.pop()
            if isinstance(node, (ast.FunctionDef, ast.AsyncFunctionDef, ast.ClassDef)):
                name = prefix + node.name
                if not isinstance(node, ast.ClassDef):
                    n = node.end_lineno - node.lineno + 1 - _docstring_lines(node)
                    if n > limit:
                        out.append((rel, name, n))
                todo += [(c, name + ".") for c in node.body]
            else:
                todo += [(c, prefix) for c in ast.iter_child_nodes(node)]
    return sorted(out)


def test_finder_measures_code_lines_of_nested_functions_and_methods(tmp_path):
    doc = '    """' + "\n".join(["doc"] * 10) + '"""\n'
    code = "".join(f"    x{i} = {i}\n" for i in range(6))
    (tmp_path / "pkg").mkdir()
    (tmp_path / "pkg" / "m.py").write_text(
        "def short():\n" + doc + code
        + "class C:\n    def long(self):\n" + "".join("    " + ln + "\n" for ln in code.splitlines())
        + "        def inner():\n" + "".join("        " + ln + "\n" for ln in code.splitlines())
        + "        return inner\n")
    (tmp_path / "other.py").write_text("def f():\n" + code * 3)
    # short: 1 + 6 code lines (its 10-line docstring not counted); C.long: 1 + 6 + 1 + 6 + 1
    assert long_functions(tmp_path, ("pkg",), limit=7) == [("pkg/m.py", "C.long", 15)]
    assert long_functions(tmp_path, ("pkg",), limit=6) == [("pkg/m.py", "C.long", 15),
                                                           ("pkg/m.py", "C.long.inner", 7),
                                                           ("pkg/m.py", "short", 7)]
    assert long_functions(tmp_path, ("other.py",), limit=18) == [("other.py", "f", 19)]


def test_no_function_over_80_lines_in_calib_and_the_marker_solve():
    found = [f"{rel}: {name} ({n} lines)" for rel, name, n in long_functions()
             if f"{rel}:{name}" not in ALLOWED]
    assert not found, "split these into named steps (issue 44):\n" + "\n".join(found)


def test_allowed_entries_are_still_long():
    """An entry of :data:`ALLOWED` whose function got shorter (or went) is stale."""
    long = {f"{rel}:{name}" for rel, name, _ in long_functions()}
    assert not set(ALLOWED) - long
