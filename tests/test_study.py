"""Batch studies: one tiny synthetic campaign (PA10 joint 5, 4 trials of 6 s, known truth) through
calibration, link angles, fits and diagnosis; serial, a 2-process pool and (when the extra is
installed) a 2-worker Dask LocalCluster give the same numbers; reruns skip what is up to date;
an interrupted study leaves no half-written files and resumes."""
from __future__ import annotations

import json
import shutil
from pathlib import Path

import numpy as np
import pytest

from ident.cli.main import main
from ident.study.executor import PoolExecutor, SerialExecutor, WorkerLost
from ident.study.study import MANIFEST_NAME, STATE_DIR, Study, StudySettings
from mocap.io.campaign import load_campaign

# fast settings: two models, few multi-starts, no recording unless a test asks for it
FAST = StudySettings(models=("cv", "stribeck"), n_starts=2, rrd=False)


@pytest.fixture(scope="module")
def tiny(tmp_path_factory):
    """A 4-trial campaign (2 speed ranges x 2 repetitions, no load) and its truth."""
    root = tmp_path_factory.mktemp("camp")
    camp = root / "tiny"
    rc = main(["synth", str(camp), "--reps", "2", "--duration", "6", "--vmax", "0.5,1.0", "--loads", "0",
               "--seed", "3", "--quiet"])
    assert rc == 0
    truth = json.loads((root / "tiny.truth.json").read_text())
    npz = np.load(root / "tiny.truth.npz")
    return camp, truth, {k: npz[k] for k in npz.files}


@pytest.fixture(scope="module")
def serial_run(tiny, tmp_path_factory):
    camp, _, _ = tiny
    out = tmp_path_factory.mktemp("serial")
    res = Study(FAST, SerialExecutor(progress=False), progress=False).run(camp, out)
    return out, res


def _fits(out: Path) -> dict:
    return json.loads((out / "fits" / "fits.json").read_text())["trials"]


def _assert_same_fits(a: dict, b: dict, rtol=1e-9):
    assert a.keys() == b.keys()
    for tid in a:
        for j in a[tid]:
            for m in a[tid][j]:
                pa, pb = a[tid][j][m]["params"], b[tid][j][m]["params"]
                for k in pa:
                    assert pb[k] == pytest.approx(pa[k], rel=rtol, abs=1e-12), (tid, j, m, k)


def test_study_outputs_match_truth(tiny, serial_run):
    camp, truth, npz = tiny
    out, res = serial_run
    c = load_campaign(camp)
    assert res.errors == {}
    assert {k: v["computed"] for k, v in res.stages.items()} == \
        {"calib": 1, "mocap": 4, "fits": 4, "diagnosis": 1, "report": 1}
    # calibration against the true camera pose: < 1 mm and < 0.05 deg
    T = np.array(json.loads((out / "calib.json").read_text())["T_camera_base"])
    T_true = np.array(truth["T_camera_base"])
    assert np.linalg.norm(T[:3, 3] - T_true[:3, 3]) < 1e-3
    ang = np.degrees(np.arccos(np.clip((np.trace(T[:3, :3].T @ T_true[:3, :3]) - 1) / 2, -1, 1)))
    assert ang < 0.05
    # link angles against the true link angle (marker noise 0.85 mm on short lever arms)
    for tr in c.trials:
        data = np.genfromtxt(out / "angles" / f"{tr.id}.csv", delimiter=",", names=True)
        q_true = np.interp(data["time"], npz[f"{tr.id}/time"], npz[f"{tr.id}/q"])
        ok = np.isfinite(data["q_5"])
        assert ok.mean() > 0.95
        err = data["q_5"][ok] - q_true[ok]
        assert np.sqrt(np.mean(err ** 2)) < 6e-3, tr.id      # per-frame noise (~3 mrad here)
        assert abs(np.mean(err)) < 1.5e-3, tr.id              # no bias
    # report pieces
    md = (out / "report.md").read_text()
    assert "Root mean square error" in md and "## Sim-to-real gap" in md
    assert (out / "plots" / "friction_joint5.png").stat().st_size > 1000
    assert (out / "plots" / "spread_joint5.png").stat().st_size > 1000
    assert (out / "diagnosis" / "joint5_localisation.png").is_file()
    rows = (out / "csv" / "trials.csv").read_text().splitlines()
    assert rows[0].startswith("trial,joint,kind") and len(rows) == 1 + 4
    man = json.loads((out / MANIFEST_NAME).read_text())
    assert set(man["stages"]["mocap"]["items"]) == {t.id for t in c.trials}
    assert all(len(v["hash"]) == 64 for v in man["stages"]["mocap"]["items"].values())
    # nothing temporary left behind
    assert not list(out.rglob("*.tmp"))
    assert not (out / STATE_DIR / "tmp").exists()



def test_study_fits_match_truth(tiny, serial_run):
    camp, truth, npz = tiny
    out, res = serial_run
    # Coulomb + viscous parameters against the simulated joint (no withheld effect): 3 % / 8 %
    # (the declared 5000 N m/rad j5: the link sticks while the motor winds the spring up)
    cv_true = truth["joints"]["5"]["true_models"]["cv"]
    for tid, joints in _fits(out).items():
        p = joints["5"]["cv"]["params"]
        assert p["c"] == pytest.approx(cv_true["c"], rel=0.03), tid
        assert p["v"] == pytest.approx(cv_true["v"], rel=0.08), tid


def test_study_verdict_matches_truth(serial_run):
    _, res = serial_run
    # no withheld effect: the diagnosis (nominal on the declared 5000 N m/rad j5) finds none
    assert res.verdicts == {"5": "none"}


@pytest.fixture(scope="module")
def pool_run(tiny, tmp_path_factory):
    camp, _, _ = tiny
    out = tmp_path_factory.mktemp("pool")
    ex = PoolExecutor(2, progress=False)
    try:
        res = Study(FAST, ex, progress=False).run(camp, out)
    finally:
        ex.close()
    return out, res


def _same_outputs(a: Path, b: Path) -> None:
    """Two study folders with the same numbers: fits, angles, diagnosis, tables, PNGs."""
    assert json.loads((a / "fits" / "fits.json").read_text()) == json.loads((b / "fits" / "fits.json").read_text())
    names = sorted(p.relative_to(a).as_posix() for p in a.rglob("*")
                   if p.is_file() and p.suffix in (".csv", ".png") and STATE_DIR not in p.parts)
    assert names and names == sorted(p.relative_to(b).as_posix() for p in b.rglob("*")
                                     if p.is_file() and p.suffix in (".csv", ".png") and STATE_DIR not in p.parts)
    for n in names:
        assert (a / n).read_bytes() == (b / n).read_bytes(), n
    da = json.loads((a / "diagnosis" / "diagnosis.json").read_text())
    db = json.loads((b / "diagnosis" / "diagnosis.json").read_text())
    assert da == db


def test_pool_of_two_gives_the_serial_numbers(tiny, serial_run, pool_run):
    out, res = pool_run
    assert res.errors == {}
    _assert_same_fits(_fits(serial_run[0]), _fits(out))
    _same_outputs(serial_run[0], out)
    assert res.verdicts == serial_run[1].verdicts


def test_rerun_skips_and_a_changed_input_reruns_only_its_trial(tiny, serial_run, tmp_path):
    camp, _, _ = tiny
    out = tmp_path / "out"
    shutil.copytree(serial_run[0], out)
    camp2 = tmp_path / "camp"
    shutil.copytree(camp, camp2)
    # same inputs (a copied campaign: same bytes, so same hashes) -> everything reused
    res = Study(FAST, None, progress=False).run(camp2, out)
    assert {k: v["computed"] for k, v in res.stages.items()} == \
        {"calib": 0, "mocap": 0, "fits": 0, "diagnosis": 0, "report": 0}
    assert res.stages["fits"]["reused"] == 4
    # change one trial's robot log (one torque sample): only that trial's fit and the diagnosis rerun
    log = camp2 / "trials" / "j5-load0-v100-r2.csv"
    lines = log.read_text().splitlines()
    cells = lines[10].split(",")
    cells[-1] = cells[-1] + "1" if "." in cells[-1] else cells[-1] + ".0001"
    lines[10] = ",".join(cells)
    log.write_text("\n".join(lines) + "\n")
    res = Study(FAST, None, progress=False).run(camp2, out)
    assert res.stages["mocap"]["computed"] == 1 and res.stages["mocap"]["reused"] == 3
    assert res.stages["fits"]["computed"] == 1 and res.stages["fits"]["reused"] == 3
    assert res.stages["diagnosis"]["computed"] == 1
    assert res.stages["calib"]["computed"] == 0
    # other settings -> the fits rerun
    res = Study(dataclass_replace(FAST, n_starts=3), None, progress=False).run(camp2, out)
    assert res.stages["fits"]["computed"] == 4 and res.stages["mocap"]["computed"] == 0
    # a calibration option (jointlab study --trust-urdf) -> the calibration reruns, and says so
    assert json.loads((out / "calib.json").read_text())["base_solve"]["urdf_trusted"] is False
    res = Study(dataclass_replace(FAST, n_starts=3, calib_trust_urdf=True), None, progress=False).run(camp2, out)
    assert res.stages["calib"]["computed"] == 1
    assert json.loads((out / "calib.json").read_text())["base_solve"]["urdf_trusted"] is True


def dataclass_replace(obj, **kw):
    import dataclasses

    return dataclasses.replace(obj, **kw)


def test_interrupted_study_leaves_no_half_files_and_resumes(tiny, serial_run, tmp_path, monkeypatch):
    camp, _, _ = tiny
    import ident.study.study as fitting   # the name the study calls

    real = fitting.fit_trial_joint
    calls = {"n": 0}

    def flaky(task):
        calls["n"] += 1
        if calls["n"] == 3:
            raise KeyboardInterrupt  # the user hits Ctrl-C during the third fit
        return real(task)

    monkeypatch.setattr(fitting, "fit_trial_joint", flaky)
    with pytest.raises(KeyboardInterrupt):
        Study(FAST, SerialExecutor(progress=False), progress=False).run(camp, tmp_path)
    # the angle files present are complete (same bytes as the uninterrupted run), no fits/ yet
    for p in (tmp_path / "angles").glob("*.csv"):
        assert p.read_bytes() == (serial_run[0] / "angles" / p.name).read_bytes()
    assert len(list((tmp_path / "angles").glob("*"))) == 4
    assert not (tmp_path / "fits").exists()
    assert not [p for p in tmp_path.rglob("*") if p.is_file() and ".tmp" in p.name
                and STATE_DIR not in p.parts]
    monkeypatch.setattr(fitting, "fit_trial_joint", real)
    res = Study(FAST, SerialExecutor(progress=False), progress=False).run(camp, tmp_path)
    assert res.stages["mocap"]["reused"] == 4
    assert res.stages["fits"]["reused"] == 2 and res.stages["fits"]["computed"] == 2
    _assert_same_fits(_fits(serial_run[0]), _fits(tmp_path))
    assert not (tmp_path / STATE_DIR / "tmp").exists()


def test_dask_local_cluster_gives_the_process_pool_results(tiny, pool_run, tmp_path):
    """The same study on a 2-worker Dask LocalCluster (worker processes): every number and
    file the process pool gave (fits, angles, diagnosis, tables, plots), the same items
    computed."""
    distributed = pytest.importorskip("distributed")
    from ident.study.executor import DaskExecutor

    camp, _, _ = tiny
    with distributed.LocalCluster(n_workers=2, threads_per_worker=1, processes=True,
                                  dashboard_address=None) as cluster, distributed.Client(cluster) as client:
        ex = DaskExecutor(client=client, progress=False)
        assert ex.workers == 2
        res = Study(FAST, ex, progress=False).run(camp, tmp_path)
        ex.close()
    assert res.errors == {}
    _same_outputs(pool_run[0], tmp_path)
    assert res.verdicts == pool_run[1].verdicts
    assert {k: v["computed"] for k, v in res.stages.items()} == \
        {k: v["computed"] for k, v in pool_run[1].stages.items()}


def test_cli_study_writes_recording_and_json(tiny, tmp_path, capsys):
    camp, _, _ = tiny
    out = tmp_path / "cli"
    rc = main(["study", str(camp), "--out", str(out), "--workers", "1", "--models", "cv",
               "--starts", "1", "--no-diagnosis", "--quiet", "--json"])
    assert rc == 0
    doc = json.loads(capsys.readouterr().out)
    assert doc["stages"]["fits"]["computed"] == 4 and doc["stages"]["diagnosis"]["note"] == "switched off"
    from rerun.chunk import RrdReader

    ents = {ch.entity_path for ch in RrdReader(out / "study.rrd").stream()}
    assert any(e.startswith("/campaign/trial/") and e.endswith("/markers") for e in ents)
    assert any(e.startswith("/fits/") for e in ents)
    assert any(e.startswith("/mocap/") for e in ents)
    assert "/study/report" in ents


def test_cli_refuses_output_inside_campaign(tiny, capsys):
    camp, _, _ = tiny
    rc = main(["study", str(camp), "--out", str(camp / "results"), "--workers", "1", "--quiet"])
    assert rc == 2
    assert "inside the input folder" in capsys.readouterr().err
    assert not (camp / "results").exists()


def test_cli_study_deflection_without_declared_stiffness_is_refused_before_any_work(tiny, tmp_path, capsys):
    camp, _, _ = tiny
    camp2 = tmp_path / "camp"
    shutil.copytree(camp, camp2)
    drives = camp2 / "robot" / "drives.toml"
    drives.write_text("".join(ln for ln in drives.read_text().splitlines(keepends=True)
                              if not ln.strip().startswith("stiffness")))
    rc = main(["study", str(camp2), "--out", str(tmp_path / "o"), "--workers", "1", "--deflection", "--quiet"])
    assert rc == 2
    err = capsys.readouterr().err
    assert "drives.toml" in err and "--deflection" in err and len(err.strip().splitlines()) == 1
    assert not (tmp_path / "o").exists()


def test_demo_without_fixture_says_how_to_regenerate(tmp_path, monkeypatch, capsys):
    import ident.cli.commands.demo as demo

    monkeypatch.setattr(demo, "demo_campaign", lambda: tmp_path / "nowhere")
    rc = main(["demo", "--out", str(tmp_path / "o"), "--workers", "1"])
    assert rc == 2
    err = capsys.readouterr().err
    assert "demo campaign is missing" in err and "jointlab synth fixtures/demo" in err


def test_settings_are_validated():
    from mocap.io.errors import InputError

    with pytest.raises(InputError, match="unknown|model"):
        StudySettings(models=("nope",)).validate()
    with pytest.raises(InputError, match="rrd_trials"):
        StudySettings(rrd_trials="some").validate()
    with pytest.raises(InputError, match="diagnosis_reps"):
        StudySettings(diagnosis_reps=-1).validate()
    with pytest.raises(InputError, match="urdf-tol-mm"):
        StudySettings(calib_urdf_tol_mm=-0.1).validate()


def test_diagnosis_reps_diagnoses_the_first_repetitions_and_fits_every_trial(tiny, tmp_path):
    """``diagnosis_reps=1``: the diagnosis of the 4-trial campaign is the one of its two
    first-repetition trials alone; the fits still cover all four."""
    import dataclasses

    camp, _, _ = tiny
    fast = dataclasses.replace(FAST, plots=False)
    res = Study(dataclasses.replace(fast, diagnosis_reps=1), None, progress=False).run(camp, tmp_path / "a")
    assert res.stages["fits"]["computed"] == 4
    assert "2 of 4 trials" in res.stages["diagnosis"]["note"]
    from ident.gap import DiagnosisSettings
    from ident.gap.campaign_diagnosis import diagnose_single_joint_campaign, load_angles_dir
    from ident.common import to_jsonable

    loaded = load_campaign(camp)
    firsts = dataclasses.replace(loaded, trials=tuple(t for t in loaded.trials if t.repetition == 1))
    assert len(firsts.trials) == 2
    angles = load_angles_dir(tmp_path / "a" / "angles", list(firsts.trials))
    ref = diagnose_single_joint_campaign(firsts, loaded.load_robot(), angles, DiagnosisSettings(seed=fast.seed),
                                         joints=[5]).to_dict()
    a = json.loads((tmp_path / "a" / "diagnosis" / "diagnosis.json").read_text())["joints"]
    assert a == json.loads(json.dumps(to_jsonable(ref["joints"])))


def test_default_diagnosis_reads_whole_repetitions_within_the_sample_budget(tiny, tmp_path, monkeypatch):
    """The default (``diagnosis_reps=None``): as many repetitions of every condition as fit the
    sample budget per joint; all of them when they fit, the first one when even two do not."""
    import dataclasses

    from ident.study import study as st

    camp, _, _ = tiny
    loaded = load_campaign(camp)
    rows = {t.id: st._log_rows(t.log) for t in loaded.trials}
    assert all(r > 100 for r in rows.values())
    keep, reps = st._within_samples(list(loaded.trials), sum(rows.values()))
    assert reps == 2 and len(keep) == 4
    firsts = [t for t in loaded.trials if t.repetition == 1]
    keep, reps = st._within_samples(list(loaded.trials), sum(rows[t.id] for t in firsts))
    assert reps == 1 and [t.id for t in keep] == [t.id for t in firsts]
    monkeypatch.setattr(st, "DIAGNOSIS_SAMPLES", 1)
    fast = dataclasses.replace(FAST, plots=False)
    res = Study(fast, None, progress=False).run(camp, tmp_path / "a")
    assert res.stages["fits"]["computed"] == 4
    assert "2 of 4 trials" in res.stages["diagnosis"]["note"] and "samples per joint" in res.stages["diagnosis"]["note"]


def test_scheduler_without_the_dask_extra_says_how_to_install(tiny, tmp_path, capsys):
    try:
        import distributed  # noqa: F401
    except ImportError:
        pass
    else:
        pytest.skip("the dask extra is installed")
    camp, _, _ = tiny
    rc = main(["study", str(camp), "--out", str(tmp_path / "o"), "--scheduler", "tcp://127.0.0.1:9"])
    assert rc == 2
    assert "jointlab[dask]" in capsys.readouterr().err


def test_two_concurrent_studies_on_one_out_both_complete(tiny, serial_run, tmp_path):
    """Two studies on one --out (issue 17): the second waits for the first's lock, then resumes
    from its records; neither crashes and the folder holds one complete study."""
    import threading

    camp, _, _ = tiny
    out = tmp_path / "shared"
    results, errors = [], []

    def one():
        try:
            results.append(Study(FAST, SerialExecutor(progress=False), progress=False).run(camp, out))
        except Exception as exc:          # a traceback in either run fails the test
            errors.append(exc)

    threads = [threading.Thread(target=one) for _ in range(2)]
    for t in threads:
        t.start()
    for t in threads:
        t.join()
    assert errors == [] and len(results) == 2
    assert all(r.errors == {} for r in results)
    first, second = sorted(results, key=lambda r: r.stages["fits"]["computed"], reverse=True)
    assert first.stages["fits"]["computed"] == 4
    assert second.stages["fits"]["reused"] == 4 and second.stages["fits"]["computed"] == 0
    _assert_same_fits(_fits(out), _fits(serial_run[0]))
    assert (out / "report.md").is_file()


def test_a_failed_first_repetition_hands_its_plot_to_the_next(tiny, tmp_path, monkeypatch):
    """The study holds plot samples only for the trials it draws; when the first repetition of
    a condition fails, the next one's samples are read back from its record and drawn."""
    import ident.study.study as fitting   # the name the study calls
    from ident.study.records import read_record
    from ident.study.study import CACHE_VERSION, _record_name

    camp, _, _ = tiny
    real = fitting.fit_trial_joint
    gone = "j5-load0-v50-r1"

    def failing(task):
        if task.trial == gone:
            raise ValueError("no fit")
        return real(task)

    monkeypatch.setattr(fitting, "fit_trial_joint", failing)
    res = Study(FAST, SerialExecutor(progress=False), progress=False).run(camp, tmp_path)
    assert list(res.errors) == [f"fits/{gone}"]
    man = json.loads((tmp_path / MANIFEST_NAME).read_text())
    rel = f"records/fits/{_record_name('j5-load0-v50-r2')}"
    h = man["stages"]["fits"]["items"]["j5-load0-v50-r2"]["hash"]
    rec, problem = read_record(tmp_path / STATE_DIR / rel, h, CACHE_VERSION)
    assert problem is None and rec["result"]["entries"][0].plot
    ref = fitting.FitsResult(tuple(rec["result"]["entries"]), FAST.models).write_plots(tmp_path / "ref")
    assert len(ref) == 1
    drawn = tmp_path / "fits" / "plots" / ref[0].name
    assert drawn.read_bytes() == ref[0].read_bytes()


def test_recording_begun_early_is_written_again_when_a_shown_trial_fails(tiny, tmp_path, monkeypatch):
    """The recording's inputs are logged while the fits run, with each condition's first
    repetition; when that trial then fails its fit, the recording is written again with the next
    repetition (what the report shows), and nothing of the first one is left."""
    import dataclasses

    import ident.study.study as fitting
    from rerun.chunk import RrdReader

    camp, _, _ = tiny
    real = fitting.fit_trial_joint
    gone, next_rep = "j5-load0-v50-r1", "j5-load0-v50-r2"

    def failing(task):
        if task.trial == gone:
            raise ValueError("no fit")
        return real(task)

    monkeypatch.setattr(fitting, "fit_trial_joint", failing)
    started = []
    real_start = fitting._StudyRecording.start

    def start(self, bad):
        started.append(set(bad))
        return real_start(self, bad)

    monkeypatch.setattr(fitting._StudyRecording, "start", start)
    settings = dataclasses.replace(FAST, rrd=True, diagnose=False)
    res = Study(settings, SerialExecutor(progress=False), progress=False).run(camp, tmp_path)
    assert list(res.errors) == [f"fits/{gone}"]
    assert started == [set()]            # begun before the fits, with no failed trial known
    ents = {ch.entity_path for ch in RrdReader(tmp_path / "study.rrd").stream()}
    assert any(f"/{next_rep}/" in e for e in ents)
    assert not any(gone in e for e in ents)
    assert not list(tmp_path.rglob("*.early.tmp"))


def test_pending_each_yields_every_item_once_then_the_results_in_order():
    ex = PoolExecutor(2, progress=False)
    try:
        p = ex.submit_map(abs, [-3, 1, -2, 5, -8], "test")
        seen = dict(p.each())
        assert sorted(seen) == [0, 1, 2, 3, 4] and seen == {0: 3, 1: 1, 2: 2, 3: 5, 4: 8}
        assert p.result() == [3, 1, 2, 5, 8]
    finally:
        ex.close()
    serial = SerialExecutor(progress=False).submit_map(abs, [-1, 2], "test")
    assert list(serial.each()) == [(0, 1), (1, 2)] and serial.result() == [1, 2]


def _exit_worker(x):
    """Kill the worker process that runs it (a worker lost to the OOM killer or a kill -9)."""
    import os

    os._exit(1)


def test_a_pool_broken_before_a_batch_is_queued_is_the_one_line_worker_error():
    """A worker that dies while this process is still queueing the next batch breaks the pool at
    ``submit``: the same one-line WorkerLost as when it dies while results are awaited."""
    import time

    ex, ex2 = PoolExecutor(2, progress=False), PoolExecutor(2, progress=False)
    try:
        first = ex.submit_map(_exit_worker, [0], "first")
        with pytest.raises(WorkerLost, match="first stage died"):
            first.result()
        ex2.submit_map(_exit_worker, [0], "first")
        for _ in range(500):            # until the pool has noticed its dead worker
            if ex2._pool._broken:
                break
            time.sleep(0.01)
        assert ex2._pool._broken
        with pytest.raises(WorkerLost, match="fits stage died"):
            ex2.submit_map(abs, [-1, 2], "fits")
        assert ex2._pool is None        # the workers were stopped
    finally:
        ex.close()
        ex2._kill()


def _big_result(mb):
    """A result of ``mb`` MiB, sent after 0.3 s: a worker killed during that send leaves half a
    message in the result pipe."""
    import time

    time.sleep(0.3)
    return b"x" * (mb << 20)


def test_a_killed_pool_leaves_no_manager_thread_blocked_on_a_half_sent_result():
    """Ctrl-C or a lost worker kills the pool; a worker terminated while it was sending a result
    leaves the pool's manager thread (which the interpreter joins at exit) reading the rest of
    that message forever, and the command would never exit. After ``_kill`` the thread has ended
    whenever the kill lands (a sweep over the moments around the send)."""
    import time

    left = []
    try:
        for k in range(11):
            ex = PoolExecutor(2, progress=False)
            ex.submit_map(_big_result, [64, 64], "big")
            mgr = ex._pool._executor_manager_thread
            time.sleep(0.3 + 0.06 * k)
            ex._kill()
            mgr.join(3.0)
            if mgr.is_alive():
                left.append(mgr)
        assert not left, f"{len(left)} of 11 kills left the manager thread blocked"
    finally:
        for mgr in left:                # let this test process exit even when the check fails
            mgr.result_queue._writer.close()
            mgr.join(5.0)


def test_fits_json_files_are_written_one_trial_at_a_time_with_the_same_bytes(tiny, serial_run):
    """``fits.json`` and ``fits_diagnostics.json`` are streamed trial by trial: the bytes are
    those of ``json.dumps`` of the whole document (which the streamed writer never holds)."""
    import io

    from ident.study.records import read_record
    from ident.study.study import CACHE_VERSION, _record_name
    from ident.thesis.campaign_fit import FitsResult, _clean_json, write_json_streamed

    camp, _, _ = tiny
    out, _ = serial_run
    man = json.loads((out / MANIFEST_NAME).read_text())
    entries = []
    for t in load_campaign(camp).trials:  # the study's entries, read back from its records
        rel = f"records/fits/{_record_name(t.id)}"
        rec, problem = read_record(out / STATE_DIR / rel, man["stages"]["fits"]["items"][t.id]["hash"],
                                   CACHE_VERSION)
        assert problem is None
        entries += rec["result"]["entries"]
    res = FitsResult(tuple(entries), FAST.models, load_campaign(camp).name)
    assert (out / "fits" / "fits.json").read_text() == json.dumps(res.to_dict(), indent=1, allow_nan=False)
    assert (out / "fits" / "fits_diagnostics.json").read_text() == \
        json.dumps(_clean_json(res.diagnostics()), indent=1, allow_nan=False)
    # the writer's edge cases: empty dictionaries, non-ASCII text, NaN cleaned, nested lists
    nested = {"a": [1.5, {"b": "Grad \u00b0"}], "t": {"x": {"y": [float("nan"), 2]}, "z": {}}, "e": {}}
    for doc in (nested, {}, {"t": {}}):
        parts = [(k, ((kk, vv) for kk, vv in v.items()) if isinstance(v, dict) else v) for k, v in doc.items()]
        s = io.StringIO()
        write_json_streamed(s, parts, clean=_clean_json)
        assert s.getvalue() == json.dumps(_clean_json(doc), indent=1, allow_nan=False)
