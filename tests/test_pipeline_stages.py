"""The pipeline's one list of stages (issue 44 item 1) and the MuJoCo replay as a stage (issue 43
item 5): the plan's order, the cache key of a stage's declared inputs, the plain runner, and the
study running a stage of the list whole (resumed when its inputs are unchanged)."""
from __future__ import annotations

import json
import shutil
from dataclasses import dataclass
from pathlib import Path

import pytest

from ident.cli.main import main
from ident.pipeline import plan as plan_mod
from ident.pipeline.plan import PipelineSettings, plan, stage_named
from ident.pipeline.stage import Context, Runtime, Stage, input_key, run_stages
from ident.pipeline.stages import sim2real as sim2real_stage
from ident.study import study as study_mod
from ident.study.executor import SerialExecutor
from ident.study.study import Study, StudySettings
from mocap.io.campaign import load_campaign
from synth_campaigns import synth


@pytest.fixture(scope="module")
def single(tmp_path_factory):
    return synth(tmp_path_factory.mktemp("stages"), "single", duration=4, seed=3)


def _quick(**kw) -> StudySettings:
    base = dict(models=("cv",), n_starts=1, mocap=False, diagnose=False, plots=False, rrd=False)
    return StudySettings(**{**base, **kw})


def test_plan_is_one_ordered_list_and_sim2real_one_setting(single):
    camp = load_campaign(single)
    names = [st.name for st in plan(camp)]
    assert names == ["calib", "mocap", "fits", "rigidbody", "diagnosis", "coastdown"]
    assert [st.name for st in plan(camp, PipelineSettings(sim2real=True))][-1] == "sim2real"
    assert "diagnosis" not in [st.name for st in plan(camp, PipelineSettings(diagnose=False))]
    # the study runs the same list, its per-item stages in the list's order
    assert [st.name for st in Study(_quick(sim2real=True, diagnose=True), progress=False).stages(camp)] == names + ["sim2real"]


@dataclass(frozen=True)
class _Opts:
    gain: float = 1.0


def test_input_key_follows_file_bytes_and_settings(tmp_path):
    f = tmp_path / "a.csv"
    f.write_text("1,2\n")
    k = input_key({"file": f, "opts": _Opts(), "n": 3})
    assert k == input_key({"n": 3, "opts": _Opts(), "file": f})          # order of names is no part
    f.write_text("1,3\n")
    assert input_key({"file": f, "opts": _Opts(), "n": 3}) != k          # one byte of an input file
    f.write_text("1,2\n")
    assert input_key({"file": f, "opts": _Opts(), "n": 3}) == k
    assert input_key({"file": f, "opts": _Opts(gain=2.0), "n": 3}) != k  # a setting
    with pytest.raises(TypeError, match="no cache key"):
        input_key({"x": object()})


def test_plain_runner_writes_what_the_commands_write(single, tmp_path):
    # jointlab fit is the fits stage of the list: the same fits.json
    camp = load_campaign(single)
    s = PipelineSettings(models=("cv",), mocap=False, plots=False)
    folder = tmp_path / "plain"
    folder.mkdir()
    done = run_stages(stage_named(plan(camp, s), "fits", "rigidbody"), Context(camp, s, folder), Runtime())
    assert done.stages["rigidbody"].status == "skipped"
    assert done.stages["fits"].status == "ran"
    rc = main(["fit", str(single), "--out", str(tmp_path / "cmd"), "--models", "cv", "--no-plots", "--json"])
    assert rc == 0
    assert (json.loads((folder / "fits.json").read_text())
            == json.loads((tmp_path / "cmd" / "fits.json").read_text()))


def test_sim2real_stage_states_why_it_does_not_run(single, tmp_path, monkeypatch):
    camp = load_campaign(single)
    ctx = Context(camp, PipelineSettings(sim2real=True), tmp_path)
    monkeypatch.setattr(sim2real_stage.importlib.util, "find_spec", lambda name: None)
    assert "MuJoCo is not installed" in sim2real_stage.skip(ctx)
    monkeypatch.undo()
    monkeypatch.setattr(sim2real_stage.importlib.util, "find_spec", lambda name: object())
    assert sim2real_stage.skip(ctx) == "no multi-joint records to replay"
    # the study: one row with the reason, nothing written, no error
    res = Study(_quick(sim2real=True), SerialExecutor(progress=False), progress=False).run(single, tmp_path / "s")
    assert res.stages["sim2real"]["note"] == "skipped: no multi-joint records to replay"
    assert not res.errors and not (tmp_path / "s" / "sim2real").exists()


def _toy_stage(calls: list) -> Stage:
    """A stage whose result is the sum of the first log's bytes (counts its runs in ``calls``)."""
    def inputs(ctx):
        return {"log": ctx.campaign.trials[0].log, "scale": 2}

    def run(inp, rt):
        calls.append(1)
        return {"sum": inp["scale"] * sum(Path(inp["log"]).read_bytes())}

    def write(result, inp, folder, rt):
        (folder / "toy.json").write_text(json.dumps(result))
        return {"toy": folder / "toy.json"}

    return Stage("toy", inputs, run, write, output="toy/toy.json")


def test_study_runs_a_list_stage_whole_and_resumes_it(single, tmp_path, monkeypatch):
    calls: list = []
    toy = _toy_stage(calls)
    monkeypatch.setattr(study_mod, "pipeline_plan", lambda camp, s: plan_mod.plan(camp, s) + [toy])
    out = tmp_path / "s"
    study = Study(_quick(), SerialExecutor(progress=False), progress=False)
    res = study.run(single, out)
    assert res.stages["toy"]["computed"] == 1 and len(calls) == 1
    log = load_campaign(single).trials[0].log
    assert json.loads((out / "toy" / "toy.json").read_text()) == {"sum": 2 * sum(log.read_bytes())}
    res = study.run(single, out)                       # inputs unchanged: the record is kept
    assert res.stages["toy"]["reused"] == 1 and len(calls) == 1
    (out / "toy" / "toy.json").write_text("{}")        # an output changed since: recomputed
    res = study.run(single, out)
    assert res.stages["toy"]["computed"] == 1 and len(calls) == 2
    data = log.read_bytes()
    log.write_bytes(data + b"\n")                      # a declared input changed: recomputed
    try:
        res = study.run(single, out)
    finally:
        log.write_bytes(data)
    assert res.stages["toy"]["computed"] == 1 and len(calls) == 3


def _untimed(doc):
    """A document without its wall times (``seconds`` keys, the optimiser's "total time" line)."""
    if isinstance(doc, dict):
        return {k: _untimed(v) for k, v in doc.items() if k != "seconds"}
    if isinstance(doc, list):
        return [_untimed(v) for v in doc if not (isinstance(v, str) and v.startswith("total time"))]
    return doc


def test_study_sim2real_stage_writes_what_the_command_writes(tmp_path):
    pytest.importorskip("mujoco", reason="MuJoCo is an optional extra: pip install '.[mujoco]'")
    multi = tmp_path / "tx40"          # the TX40 record cut to 3 s (a quick replay)
    shutil.copytree(Path(__file__).resolve().parents[1] / "fixtures" / "real" / "tx40", multi)
    log = multi / "trials" / "excitation.csv"
    lines = log.read_text().splitlines()
    t0 = float(lines[1].split(",")[0])
    log.write_text("\n".join([lines[0]] + [ln for ln in lines[1:] if float(ln.split(",")[0]) - t0 <= 3.0]) + "\n")
    out = tmp_path / "study"
    res = Study(_quick(sim2real=True), SerialExecutor(progress=False), progress=False).run(multi, out)
    assert not res.errors, res.errors
    assert res.stages["sim2real"]["computed"] == 1
    assert main(["sim2real", str(multi), "--out", str(tmp_path / "cmd")]) == 0
    mine = json.loads((out / "sim2real" / "sim2real.json").read_text())
    cmd = json.loads((tmp_path / "cmd" / "sim2real.json").read_text())
    assert _untimed(mine) == _untimed(cmd)
    assert sorted(p.name for p in (out / "sim2real").iterdir()) == sorted(
        p.name for p in (tmp_path / "cmd").iterdir() if not p.name.startswith("."))
    res = Study(_quick(sim2real=True), SerialExecutor(progress=False), progress=False).run(multi, out)
    assert res.stages["sim2real"]["reused"] == 1
