"""Small synthesised campaigns shared by the pipeline tests: ``jointlab synth`` at the tests'
short settings, and a mixed campaign (a multi-joint record's manifest with single-joint trials
appended)."""
from __future__ import annotations

import shutil
from pathlib import Path

from ident.cli.main import main


def synth(root: Path, name: str, *opts, duration: float = 5.0, seed: int = 5) -> Path:
    """``jointlab synth ROOT/NAME`` (one repetition of ``duration`` s, no load) with ``opts``."""
    out = root / name
    rc = main(["synth", str(out), "--reps", "1", "--duration", f"{duration:g}", "--vmax", "1.0", "--loads", "0",
               "--seed", str(seed), "--quiet", *opts])
    assert rc == 0
    return out


def mixed_campaign(single: Path, multi: Path, out: Path) -> Path:
    """``multi``'s campaign with ``single``'s trials (files and manifest entries) appended."""
    shutil.copytree(multi, out)
    for p in (single / "trials").iterdir():
        shutil.copy(p, out / "trials" / p.name)
    text = (single / "campaign.toml").read_text(encoding="utf-8")
    with open(out / "campaign.toml", "a", encoding="utf-8") as fh:
        fh.write("\n" + text[text.index("[[trial]]"):])
    return out
