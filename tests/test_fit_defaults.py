"""Issue 45: ``jointlab fit`` without ``--models`` chooses its models from the campaign's shape
(ident.workflow.default_models): a multi-joint campaign without markers fits ``cv`` only and
says so in one line; a single-joint motion-capture campaign keeps the thesis set."""
from __future__ import annotations

import json

from ident import workflow
from ident.cli.main import main
from mocap.io.campaign import load_campaign
from tests_paths import DEMO, REPO

TIAGO = REPO / "fixtures" / "real" / "tiago"


def test_multijoint_markerless_campaign_fits_cv_only_and_says_so(tmp_path, capsys):
    assert main(["fit", str(TIAGO), "--out", str(tmp_path / "fit")]) == 0
    out = capsys.readouterr().out
    said = [ln for ln in out.splitlines() if "fitting cv only" in ln]
    assert len(said) == 1 and "without markers" in said[0] and "--models" in said[0]
    doc = json.loads((tmp_path / "fit" / "fits.json").read_text())
    assert {m for by_model in doc["trials"]["arm"].values() for m in by_model} == {"cv"}


def test_default_models_follow_the_campaign_shape():
    assert workflow.default_models(load_campaign(DEMO)) == (workflow.THESIS_MODELS, None)
    models, why = workflow.default_models(load_campaign(TIAGO))
    assert models == ("cv",) and why
