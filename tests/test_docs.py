"""Documentation site (docs/): the equation map names definitions that exist and covers the three
source papers; every object an equation cites resolves; FORMAT.md and DESIGN.md are copied from
their one source; the pages' relative links and the validation page's commands resolve. The site
itself is built with warnings as errors by ``.ci/run``."""
from __future__ import annotations

import importlib
import re
import sys
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]
DOCS = ROOT / "docs"
sys.path.insert(0, str(DOCS))
import sync_format  # noqa: E402  (docs/sync_format.py)


def _resolve(dotted: str):
    """Import the longest module prefix of ``dotted`` and walk the attributes after it."""
    parts = dotted.split(".")
    for i in range(len(parts), 0, -1):
        try:
            obj = importlib.import_module(".".join(parts[:i]))
        except ImportError:
            continue
        for name in parts[i:]:
            obj = getattr(obj, name, None)
            if obj is None:
                return None
        return obj
    return None


def _map_rows():
    text = (DOCS / "equations.md").read_text(encoding="utf-8")
    start = text.index("## Where each equation lives")
    end = text.index("\n## ", start + 10)
    rows = []
    for line in text[start:end].splitlines():
        m = re.search(r"`([\w/]+\.py)::([\w.]+)`", line)
        if m:
            rows.append((line.split("|")[1].strip(), m.group(1), m.group(2)))
    return rows


def test_equation_map_covers_the_three_sources():
    rows = _map_rows()
    assert len(rows) >= 25
    assert {r[0].split()[-1] for r in rows} == {"002", "001", "000"}


def test_every_named_definition_exists():
    missing = []
    for _, path, name in _map_rows():
        assert (ROOT / path).is_file(), path
        if _resolve(path[:-3].replace("/", ".") + "." + name) is None:
            missing.append(f"{path}::{name}")
    assert not missing, missing


def test_equations_are_rendered_and_cite_existing_objects():
    text = (DOCS / "equations.md").read_text(encoding="utf-8")
    labels = re.findall(r"^\$\$ \(([\w-]+)\)$", text, re.M)
    assert len(labels) >= 20 and len(set(labels)) == len(labels)
    cited = re.findall(r"\{py:\w+\}`([\w.]+)`", text)
    assert len(cited) >= 25
    assert [c for c in cited if _resolve(c) is None] == []


@pytest.mark.parametrize("name,page", sorted(sync_format.PAGES.items()))
def test_synced_pages_match_their_source(name, page):
    src = ROOT.parent / "shared" / name
    if not src.is_file():
        pytest.skip(f"{src} absent (checked where the shared folder exists)")
    assert (DOCS / page).read_text(encoding="utf-8") == sync_format.rendered(src), (
        f"docs/{page} differs from {src}: run python docs/sync_format.py")


def test_sync_writes_and_then_finds_nothing_stale(tmp_path):
    shared, docs = tmp_path / "shared", tmp_path / "docs"
    shared.mkdir(), docs.mkdir()
    (shared / "FORMAT.md").write_text("# Format\n\nv1\n")
    assert sync_format.stale(shared, docs) == ["format.md"]  # DESIGN.md absent: skipped
    assert sync_format.sync(shared, docs) == ["format.md"]
    assert sync_format.stale(shared, docs) == []
    assert (docs / "format.md").read_text().endswith("# Format\n\nv1\n")
    (shared / "FORMAT.md").write_text("# Format\n\nv2\n")
    assert sync_format.stale(shared, docs) == ["format.md"]
    assert sync_format.main(["--check", "--shared", str(shared)]) == 1


def test_index_includes_every_page_by_glob():
    text = (DOCS / "index.md").read_text(encoding="utf-8")
    assert re.search(r"```\{toctree\}.*?:glob:.*?\n\*\n```", text, re.S)


def test_relative_links_resolve():
    missing = []
    for page in sorted(DOCS.glob("*.md")):
        for link in re.findall(r"\]\(([^)#:]+)(?:#[^)]*)?\)", page.read_text(encoding="utf-8")):
            if not (page.parent / link).exists():
                missing.append(f"{page.name}: {link}")
    assert not missing, missing


def test_validation_commands_name_existing_scripts():
    text = (DOCS / "validation.md").read_text(encoding="utf-8")
    rows = [ln for ln in text.splitlines() if ln.startswith("| ") and not ln.startswith("| what")
            and "---" not in ln and ln.count(" | ") >= 2]
    measured = [r for r in rows if len(r.split(" | ")) == 3]
    assert len(measured) >= 10
    for row in measured:
        reproduce = row.rstrip(" |").split(" | ")[-1]
        assert "benchmarks/" in reproduce or "jointlab " in reproduce, row
    for script in set(re.findall(r"benchmarks/\w+\.py", text)):
        assert (ROOT / script).is_file(), script


def test_api_reference_covers_the_four_packages():
    text = (DOCS / "api.rst").read_text(encoding="utf-8")
    assert ":recursive:" in text
    assert {"calib", "mocap", "ident", "viz"} <= set(re.findall(r"^   (\w+)$", text, re.M))
