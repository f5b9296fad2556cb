"""Every public entry point (the names in a package's ``__all__``) carries a numpydoc docstring:
a one-line summary, ``Parameters`` (functions that take any; classes: the constructor's
parameters, dataclasses their fields, as ``Parameters`` or ``Attributes``), ``Returns`` (functions
that return a value), ``References``, and no documented parameter that the signature lacks or
the other way round (numpydoc's validation checks PR01/PR02, RT01, SS06 in spirit). Docstrings
are parsed with :mod:`numpydoc.docscrape`; the runnable ``Examples`` of these entry points run as
doctests here.

``PACKAGES`` holds the packages whose ``__all__`` is checked (the checks apply unchanged to a
package added to it). ``ENTRY_POINTS`` names, by dotted path, the
user-facing definitions of modules that no checked ``__all__`` lists (what the CLI commands, the
study and the documentation call): functions, classes and the public methods users call
(``self`` is not a documented parameter; a classmethod's ``cls`` is bound away).
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

#: packages whose ``__all__`` is checked
PACKAGES = ["calib", "ident.friction", "ident.gap", "ident.workflow", "mocap", "viz"]


#: user-facing definitions outside the checked ``__all__`` (module path, then the attribute path)
ENTRY_POINTS = [
    "mocap.robot.Robot",
    "mocap.robot.Robot.from_urdf",
    "mocap.robot.Robot.rnea",
    "mocap.robot.Robot.mass_matrix",
    "mocap.robot.Robot.gravity_torque",
    "mocap.robot.Robot.frame_transform",
    "mocap.robot.Robot.single_joint_dynamics",
    "mocap.robot.Robot.held_deflection",
    "mocap.robot.Drive",
    "mocap.robot.read_drives",
    "mocap.solve.MarkerSolver",
    "mocap.solve.MarkerSolver.fit",
    "mocap.solve.SolveResult",
    "mocap.solve.AnglesResult",
    "mocap.solve.solve_trial",
    "mocap.solve.held_placement",
    "mocap.solve.refine_markers",
    "mocap.kinematics.Chain",
    "mocap.kinematics.Chain.frame_transform",
    "mocap.numerics.rotation_about_axis",
    "mocap.kinematics.invert_transform",
    "mocap.kinematics.kabsch_batch",
    "mocap.urdf.check_urdf",
    "mocap.urdf.missing_meshes",
    "mocap.urdf.select_chain",
    "mocap.references.References",
    "mocap.references.fit_references",
    "mocap.references.build_references",
    "mocap.references.read_calib",
    "mocap.io.trc.read_trc",
    "mocap.io.trc.write_trc",
    "mocap.io.c3d.read_c3d",
    "mocap.io.c3d.write_c3d",
    "mocap.io.robotlog.RobotLog",
    "mocap.io.robotlog.read_robot_log",
    "mocap.io.robotlog.write_robot_log",
    "mocap.io.campaign.Campaign",
    "mocap.io.campaign.Campaign.load_robot",
    "mocap.io.campaign.Campaign.read_log",
    "mocap.io.campaign.Trial",
    "mocap.io.campaign.load_campaign",
    "ident.coastdown.estimators.CoastdownResult",
    "ident.coastdown.estimators.stop_time",
    "ident.coastdown.estimators.coast_velocity",
    "ident.coastdown.estimators.tdm",
    "ident.coastdown.estimators.fdm",
    "ident.coastdown.estimators.nls",
    "ident.coastdown.estimators.crb",
    "ident.coastdown.estimators.record_spectrum",
    "ident.coastdown.angle.coast_angle",
    "ident.coastdown.angle.AngleCoastFit",
    "ident.coastdown.angle.find_coasts",
    "ident.excitation.design.ExcitationDesigner",
    "ident.excitation.design.limits_from_robot",
    "ident.excitation.design.regressor_cond",
    "ident.excitation.trajectories.fourier_excitation",
    "ident.excitation.trajectories.min_jerk_path",
    "mocap.numerics.savgol_window",
    "mocap.numerics.differentiate",
    "ident.signals.smoothing.SavGolSmoother",
    "ident.signals.smoothing.FourierSmoother",
    "ident.signals.smoothing.FourierSmoother.fit",
    "ident.signals.smoothing.JointSignals",
    "ident.model.onelink.OneLinkIdentifier",
    "ident.model.onelink.OneLinkIdentifier.fit",
    "ident.model.onelink.OneLinkIdentifier.fit_signals",
    "ident.model.onelink.fit_cv_linear",
    "ident.model.onelink.model_class",
    "ident.model.onelink.onelink_target",
    "ident.model.onelink.onelink_regressor",
    "ident.model.multijoint.fit_multijoint_campaign",
    "ident.model.multijoint.diagnose_records",
    "ident.model.multijoint.multijoint_trials",
    "ident.model.linkstate.LinkStateEstimator",
    "ident.model.linkstate.prepare_joint_signals",
    "ident.model.regressor.base_parameters",
    "ident.model.regressor.ChainDynamics",
    "ident.model.regressor.ChainDynamics.from_model",
    "ident.model.regressor.ChainDynamics.regressor",
    "ident.model.regressor.BaseParameters",
]


def _resolve(dotted: str):
    """The object of a dotted name: the longest importable module prefix, then attributes."""
    parts = dotted.split(".")
    for k in range(len(parts) - 1, 0, -1):
        try:
            obj = importlib.import_module(".".join(parts[:k]))
        except ModuleNotFoundError:
            continue
        for attr in parts[k:]:
            obj = getattr(obj, attr)
        return obj
    raise ImportError(dotted)


def _entry_points():
    out = [pytest.param(_resolve(name), id=name) for name in ENTRY_POINTS]
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
    params = list(inspect.signature(obj).parameters.values())
    if (inspect.isfunction(obj) and "." in obj.__qualname__.replace(".<locals>.", "")
            and params and params[0].name == "self"):
        params = params[1:]                      # a method looked up on its class
    return [stars.get(p.kind, "") + p.name for p in params]


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


def _doctests(obj):
    return [t for t in doctest.DocTestFinder(recurse=False).find(obj, obj.__name__, globs={})
            if t.examples]


@pytest.mark.parametrize("obj", [p for p in _entry_points() if _doctests(p.values[0])])
def test_entry_point_examples_run(obj):
    tests = _doctests(obj)
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


class _Methods:
    """A class with a documented and an undocumented method."""

    def good(self, a):
        """One line.

        Parameters
        ----------
        a : int
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

    def bad(self, a):
        """One line."""
        return a


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
    # a method: ``self`` is not a parameter to document, the others are
    assert numpydoc_problems(_Methods.good) == []
    found = " | ".join(numpydoc_problems(_Methods.bad))
    assert "not documented: ['a']" in found and "self" not in found, found


def test_entry_points_are_listed_once_and_resolve():
    assert len(ENTRY_POINTS) == len(set(ENTRY_POINTS))
    for name in ENTRY_POINTS:
        obj = _resolve(name)
        assert inspect.isfunction(obj) or inspect.ismethod(obj) or inspect.isclass(obj), name
        assert f"{obj.__module__}.{obj.__qualname__}" == name, name
