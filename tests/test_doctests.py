"""The runnable examples (numpydoc ``Examples`` sections) of the public entry points run and give
what they show. Each module below must hold examples; together at least 10 entry points."""
from __future__ import annotations

import doctest
import importlib

import pytest

MODULES = [
    "ident.coastdown.estimators",
    "ident.coastdown.angle",
    "ident.excitation.design",
    "ident.excitation.trajectories",
    "ident.effects",
    "ident.common",
    "ident.settings",
    "ident.friction.registry",
    "viz.plots",
    "mocap.quality",
    "mocap.references",
    "calib.geometry",
]
FLAGS = doctest.NORMALIZE_WHITESPACE


@pytest.mark.parametrize("name", MODULES)
def test_examples_run(name):
    module = importlib.import_module(name)
    result = doctest.testmod(module, optionflags=FLAGS, verbose=False, report=True)
    assert result.attempted > 0, f"{name} has no examples"
    assert result.failed == 0, f"{result.failed} of {result.attempted} examples of {name} failed"


def test_at_least_ten_entry_points_have_examples():
    finder = doctest.DocTestFinder()
    with_examples = set()
    for name in MODULES:
        module = importlib.import_module(name)
        for test in finder.find(module):
            if test.examples and "Examples\n" in (test.docstring or ""):
                with_examples.add(test.name)
    assert len(with_examples) >= 10, sorted(with_examples)
