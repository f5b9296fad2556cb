"""Paths for tests (importable as a module because tests/ is on sys.path under pytest)."""
from pathlib import Path

REPO = Path(__file__).resolve().parents[1]
DEMO = REPO / "fixtures" / "demo"
