"""README: a user's guide of at most ~200 lines whose commands are real.

The Quick start's two command lines name extras that pyproject.toml declares and a subcommand
that exists; the commands table and the CLI list the same subcommands; every ``jointlab``
command of the worked examples parses with the real argument parser; every relative link
resolves. (The equation map moved to docs/equations.md: tests/test_docs.py checks it.)
"""
from __future__ import annotations

import re
import shlex
import tomllib
from pathlib import Path

import pytest

from ident.cli.main import build_parser

ROOT = Path(__file__).resolve().parents[1]
README = (ROOT / "README.md").read_text(encoding="utf-8")


def _section(title: str) -> str:
    start = README.index(f"## {title}")
    end = README.find("\n## ", start + 3)
    return README[start:] if end < 0 else README[start:end]


def _bash_lines(text: str) -> list[str]:
    lines = []
    for block in re.findall(r"```bash\n(.*?)```", text, re.S):
        lines += [ln.split("  #")[0].strip() for ln in block.splitlines() if ln.strip()]
    return lines


def _subcommands() -> set[str]:
    parser = build_parser()
    sub = next(a for a in parser._actions if a.dest == "command")
    return set(sub.choices)


def test_readme_is_a_short_guide():
    assert len(README.splitlines()) <= 210


def test_quick_start_commands():
    lines = _bash_lines(_section("Quick start"))
    assert len(lines) == 2
    declared = set(tomllib.loads((ROOT / "pyproject.toml").read_text())["project"]
                   ["optional-dependencies"])
    for line in lines:
        assert line.startswith("python3 -m venv .venv && . .venv/bin/activate && pip install -e ")
        m = re.search(r'pip install -e "?\.(?:\[([\w,]+)\])?"?', line)
        assert m, line
        extras = set(filter(None, (m.group(1) or "").split(",")))
        assert extras <= declared, (extras, declared)
    assert lines[0].endswith("jointlab demo --out demo-study")
    assert lines[1].endswith("python -m pytest -q")
    assert "demo" in _subcommands()


def test_commands_table_lists_every_subcommand():
    table = _section("Commands")
    named = set(re.findall(r"^\| `jointlab (\w+)", table, re.M))
    assert named == _subcommands()


def _example_commands():
    out = []
    for line in _bash_lines(README):
        for part in line.split("&&"):
            part = part.strip()
            if part.startswith("jointlab "):
                out.append(part)
    return out


@pytest.mark.parametrize("command", _example_commands())
def test_example_commands_parse(command):
    args = build_parser().parse_args(shlex.split(command)[1:])
    assert args.command == shlex.split(command)[1]


def test_examples_cover_every_command_family():
    used = {shlex.split(c)[1] for c in _example_commands()}
    families = [{"info", "view"}, {"synth"}, {"calib", "mocap"}, {"fit", "coastdown", "design"},
                {"diagnose"}, {"study", "demo"}]
    assert all(used & f for f in families), used


def test_relative_links_resolve():
    links = re.findall(r"\]\(([^)#:]+)(?:#[^)]*)?\)", README)
    assert links
    missing = [ln for ln in links if not (ROOT / ln).exists()]
    assert not missing, missing


def test_bundled_paths_exist():
    for path in set(re.findall(r"\bfixtures/[\w/.-]+", README)):
        assert (ROOT / path.rstrip(".")).exists(), path
