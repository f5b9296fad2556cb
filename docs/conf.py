"""Sphinx configuration of the jointlab documentation (``python -m sphinx -W -b html docs
docs/_build/html``)."""
from __future__ import annotations

import os
import re
import sys
import types
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))
os.environ.setdefault("MPLBACKEND", "Agg")
# ``python -m ident.cli`` runs the CLI on import; the API walk imports every module, so that one
# is stood in for by an empty module (it defines nothing to document).
sys.modules.setdefault("ident.cli.__main__", types.ModuleType("ident.cli.__main__"))

project = "jointlab"
author = "jointlab contributors"
copyright = "jointlab contributors"
release = version = "0.1.0"

extensions = [
    "myst_parser",
    "sphinx.ext.autodoc",
    "sphinx.ext.autosummary",
    "sphinx.ext.mathjax",
    "sphinx.ext.viewcode",
    "numpydoc",
]

source_suffix = {".md": "markdown", ".rst": "restructuredtext"}
root_doc = "index"
exclude_patterns = ["_build", "Thumbs.db", ".DS_Store"]
# FORMAT.md's JSON examples hold placeholders (``[x,y,z]``): shown unhighlighted, not an error
suppress_warnings = ["misc.highlighting_failure"]
myst_enable_extensions = ["dollarmath", "amsmath"]
myst_heading_anchors = 3

autosummary_generate = True
autosummary_imported_members = False
autodoc_default_options = {"members": True, "show-inheritance": True}
autodoc_member_order = "bysource"
autodoc_typehints = "none"

numpydoc_show_class_members = False
numpydoc_class_members_toctree = False
numpydoc_validation_checks: set[str] = set()

html_theme = "alabaster"
html_static_path: list[str] = []

_LITERAL = re.compile(r"(``.*?``)")


def escape_bars(app, what, name, obj, options, lines):
    """Docstrings write ``|x|`` for an absolute value; reStructuredText would read it as a
    substitution reference (jointlab defines none), so bars outside inline literals, maths roles
    and literal blocks are escaped before numpydoc and docutils see them."""
    in_block = False
    block_indent = 0
    for i, line in enumerate(lines):
        stripped = line.lstrip()
        indent = len(line) - len(stripped)
        if in_block:
            if stripped and indent <= block_indent:
                in_block = False
            else:
                continue
        if "|" in line and not stripped.startswith((">>>", "...", ".. math")):
            parts = _LITERAL.split(line)
            lines[i] = "".join(p if p.startswith("``") or ":math:`" in p else p.replace("|", r"\|")
                               for p in parts)
        if stripped.endswith("::") or stripped.startswith(".. math::"):
            in_block, block_indent = True, indent


def setup(app):
    app.connect("autodoc-process-docstring", escape_bars, priority=100)
