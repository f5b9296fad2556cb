"""Every public entry point (the names in a package's ``__all__``) carries a numpydoc docstring:
a one-line summary, ``Parameters`` (functions that take any; classes: the constructor's
parameters, dataclasses their fields, as ``Parameters`` or ``Attributes``), ``Returns`` (functions
that return a value), ``References``, and no documented parameter that the signature lacks or
the other way round (numpydoc's validation checks PR01/PR02, RT01, SS06 in spirit). Docstrings
are parsed with :mod:`numpydoc.docscrape`; the runnable ``Examples`` of these entry points run as
doctests here.

``PACKAGES`` holds the packages whose entry points pass today; ``calib``
joins it once its entry points do (the checks apply unchanged).
"""
from __future__ import annotations

import ast
import doctest
import importlib
import inspect
import textwrap
import warnings

import pytest

docscrape = pytest.importorskip("numpydoc.docscrape", reason="numpydoc: pip install -e .[docs]")
ClassDoc, FunctionDoc = docscrape.ClassDoc, docscrape.FunctionDoc

#: packages whose ``__all__`` is checked (extend with "calib" when it passes)
PACKAGES = ["ident.friction", "ident.gap", "ident.workflow", "mocap", "viz"]


def _entry_points():
    out = []
    for pkg in PACKAGES:
        module = importlib.import_module(pkg)
        for name in module.__all__:
            obj = getattr(module, name)
            if inspect.isfunction(obj) or inspect.isclass(obj):
                out.append(pytest.param(obj, id=f"{pkg}.{name}"))
    return out


def _returns_value(fn) -> bool:
    """Whether the body of ``fn`` (not of functions nested in it) returns a value or yields."""
    tree = ast.parse(textwrap.dedent(inspect.getsource(inspect.unwrap(fn))))
    fdef = tree.body[0]
    todo = list(fdef.body)
    while todo:
        node = todo.pop()
        if isinstance(node, (ast.FunctionDef, ast.AsyncFunctionDef, ast.Lambda, ast.ClassDef)):
            continue
        if isinstance(node, (ast.Yield, ast.YieldFrom)):
            return True
        if isinstance(node, ast.Return) and node.value is not None and not (
                isinstance(node.value, ast.Constant) and node.value.value is None):
            return True
        todo.extend(ast.iter_child_nodes(node))
    return False


def _signature_names(obj) -> list[str]:
    """Parameter names as numpydoc documents them: ``*args``, ``**kwargs`` with their stars."""
    stars = {inspect.Parameter.VAR_POSITIONAL: "*", inspect.Parameter.VAR_KEYWORD: "**"}
    return [stars.get(p.kind, "") + p.name for p in inspect.signature(obj).parameters.values()]


def _documented(section) -> list[str]:
    """Names of a numpydoc parameter list (``a, b : float`` documents two)."""
    return [n.strip().replace("\\", "") for p in section for n in p.name.split(",") if n.strip()]


def numpydoc_problems(obj) -> list[str]:
    """What the docstring of a public function or class lacks (empty: nothing)."""
    with warnings.catch_warnings():
        warnings.simplefilter("error")           # an unknown or misspelt section is an error
        try:
            doc = (ClassDoc(obj, config={"show_class_members": False}) if inspect.isclass(obj)
                   else FunctionDoc(obj))
        except Exception as exc:                 # noqa: BLE001  (reported as the problem)
            return [f"docstring does not parse: {exc}"]
    problems = []
    if len(doc["Summary"]) != 1 or not doc["Summary"][0].strip():
        problems.append(f"summary is not one line: {doc['Summary']}")
    params = _documented(doc["Parameters"]) + _documented(doc["Other Parameters"])
    sig = _signature_names(obj)
    if inspect.isclass(obj):
        attrs = _documented(doc["Attributes"])
        if not params and not attrs:
            problems.append("no Parameters or Attributes section")
        undocumented = [n for n in sig if n not in params and n not in attrs]
    else:
        if sig and not params:
            problems.append("no Parameters section")
        if _returns_value(obj) and not (doc["Returns"] or doc["Yields"]):
            problems.append("no Returns section")
        undocumented = [n for n in sig if n not in params]
    if undocumented:
        problems.append(f"signature parameters not documented: {undocumented}")
    unknown = [n for n in params if n not in sig]
    if unknown:
        problems.append(f"documented parameters not in the signature: {unknown}")
    if len(params) != len(set(params)):
        problems.append(f"a parameter is documented twice: {params}")
    if not "".join(doc["References"]).strip():
        problems.append("no References section")
    return problems


@pytest.mark.parametrize("obj", _entry_points())
def test_entry_point_has_numpydoc_sections(obj):
    problems = numpydoc_problems(obj)
    assert not problems, "; ".join(problems)


@pytest.mark.parametrize("obj", _entry_points())
def test_entry_point_examples_run(obj):
    tests = [t for t in doctest.DocTestFinder(recurse=False).find(obj, obj.__name__,
                                                                      globs={}) if t.examples]
    if not tests:
        pytest.skip("no Examples section")
    module = importlib.import_module(obj.__module__)
    runner = doctest.DocTestRunner(optionflags=doctest.NORMALIZE_WHITESPACE)
    for t in tests:
        t.globs = dict(vars(module))
        runner.run(t)
    assert runner.failures == 0, f"{runner.failures} of {runner.tries} examples failed"


def _bad(a, b=1):
    """Two lines of
    summary.

    Parameters
    ----------
    a : int
        Documented.
    c : int
        Not in the signature.
    """
    return a + b


class _BadClass:
    """A class with constructor parameters and no sections."""

    def __init__(self, x):
        self.x = x


def _good(a, *args, **kw):
    """One line.

    Parameters
    ----------
    a : int
        Documented.
    *args : int
        Documented.
    **kw : int
        Documented.

    Returns
    -------
    int
        Something.

    References
    ----------
    .. [1] A source.
    """
    return a


def test_the_check_fails_on_a_bad_docstring_and_passes_a_good_one():
    found = " | ".join(numpydoc_problems(_bad))
    for what in ("summary is not one line", "no Returns section", "not documented: ['b']",
                 "not in the signature: ['c']", "no References section"):
        assert what in found, found
    found = " | ".join(numpydoc_problems(_BadClass))
    assert "no Parameters or Attributes section" in found and "['x']" in found, found
    assert numpydoc_problems(_good) == []
