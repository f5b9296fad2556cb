"""Paths for tests (importable as a module because tests/ is on sys.path under pytest)."""
import re
from pathlib import Path

REPO = Path(__file__).resolve().parents[1]
DEMO = REPO / "fixtures" / "demo"
SHARED_REAL = REPO.parent / "shared" / "data" / "real"
FIXTURE_REAL = REPO / "fixtures" / "real"


def real_file(rel: str) -> Path:
    """A real recording ``rel`` (e.g. ``trc/pyomeca_markers.trc``) from ``../shared/data/real``,
    else from the copy in ``fixtures/real`` (fixtures/real/PROVENANCE.md); a skip when neither
    has it."""
    import pytest

    for base in (SHARED_REAL, FIXTURE_REAL):
        if (base / rel).is_file():
            return base / rel
    pytest.skip(f"{rel} is neither in {SHARED_REAL} nor in {FIXTURE_REAL}")


def real_names(sub: str, pattern: str) -> list:
    """File names matching ``pattern`` in ``sub`` of the shared real-data folder, else of
    ``fixtures/real``."""
    for base in (SHARED_REAL, FIXTURE_REAL):
        if (base / sub).is_dir():
            names = sorted(p.name for p in (base / sub).glob(pattern))
            if names:
                return names
    return []


def set_first_trial_key(toml: Path, key: str, value: str) -> Path:
    """Give the manifest's first [[trial]] ``key = value`` (TOML text), replacing the key where
    the trial has it."""
    text = toml.read_text()
    start = text.index("[[trial]]")
    end = text.index("[[trial]]", start + 1)
    first = re.sub(rf"^{key} = .*\n", "", text[start:end], flags=re.M)
    first = first.replace("[[trial]]\n", f"[[trial]]\n{key} = {value}\n", 1)
    toml.write_text(text[:start] + first + text[end:])
    return toml
