"""Paths for tests (importable as a module because tests/ is on sys.path under pytest)."""
import re
from pathlib import Path

REPO = Path(__file__).resolve().parents[1]
DEMO = REPO / "fixtures" / "demo"


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
