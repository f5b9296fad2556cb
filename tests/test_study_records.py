"""A study folder is data, not code (issue 31): records are JSON checked against their hashes,
a pickle planted in the records folder is never executed, an output changed behind the study's
back is recomputed, a file another command wrote is refused, a killed worker or Ctrl-C with two
workers ends in one stderr line (exit 1 / 130) and a rerun resumes to a clean run's results."""
from __future__ import annotations

import json
import os
import pickle
import shutil
import signal
import subprocess
import sys
import time
from pathlib import Path

import numpy as np
import pytest

from ident.cli.main import main
from ident.outputs import MANIFEST
from ident.study.records import decode, dumps_record, encode, read_record
from ident.study.study import STATE_DIR

ROOT = Path(__file__).resolve().parents[1]
FAST = ["--models", "cv", "--starts", "1", "--no-rrd", "--no-plots", "--quiet"]


@pytest.fixture(scope="module")
def tiny(tmp_path_factory):
    """A 4-trial synthetic campaign with [[calib]] sweeps (PA10 joint 5)."""
    camp = tmp_path_factory.mktemp("camp") / "tiny"
    assert main(["synth", str(camp), "--reps", "2", "--duration", "6", "--vmax", "0.5,1.0",
                 "--loads", "0", "--seed", "5", "--quiet"]) == 0
    return camp


@pytest.fixture(scope="module")
def clean(tiny, tmp_path_factory):
    """An uninterrupted serial study: the reference every resumed run must equal."""
    out = tmp_path_factory.mktemp("clean") / "out"
    assert main(["study", str(tiny), "--out", str(out), "--workers", "1", "--json"] + FAST) == 0
    return out


def _study(camp, out, *extra, capsys=None):
    rc = main(["study", str(camp), "--out", str(out), "--workers", "1", "--json", *extra] + FAST)
    doc = None
    if capsys is not None:
        cap = capsys.readouterr()
        doc = json.loads(cap.out) if rc in (0, 1) and cap.out.strip() else None
        return rc, doc, cap.err
    return rc, doc, ""


def _params(out: Path) -> dict:
    doc = json.loads((out / "fits" / "fits.json").read_text())["trials"]
    return {(t, j, m): e["params"] for t, js in doc.items() for j, ms in js.items() for m, e in ms.items()}


def _angles(out: Path) -> dict:
    return {p.name: p.read_bytes() for p in sorted((out / "angles").glob("*.csv"))}


def _same_as_clean(out: Path, clean: Path) -> None:
    assert _angles(out) == _angles(clean)
    assert _params(out) == _params(clean)          # exact: same inputs, same seeds, same code
    a = json.loads((out / "diagnosis" / "diagnosis.json").read_text())["joints"]
    b = json.loads((clean / "diagnosis" / "diagnosis.json").read_text())["joints"]
    assert {j: r["verdict"] for j, r in a.items()} == {j: r["verdict"] for j, r in b.items()}


class _Payload:
    """Unpickling this creates the marker file (what an attacker's payload would do)."""

    def __init__(self, marker):
        self.marker = str(marker)

    def __reduce__(self):
        return (open, (self.marker, "w"))


# ---------------------------------------------------------------------------------------------
def test_codec_round_trips_bit_for_bit_and_refuses_foreign_types(tmp_path):
    from calib.base import BasePlacement  # noqa: F401  (a project dataclass: allowed)

    x = {"a": np.array([[1.5, np.nan], [np.inf, -0.0]]), 3: (1, "x", None), "b": [np.float64(1e-300)],
         "p": Path("/x/y"), "flag": np.bool_(True), "i": np.arange(3, dtype=np.int32)}
    y = decode(json.loads(json.dumps(encode(x))))
    assert y[3] == (1, "x", None) and y["p"] == Path("/x/y") and y["flag"] is True
    assert y["a"].tobytes() == x["a"].tobytes() and y["i"].dtype == np.int32
    with pytest.raises(TypeError):
        encode(object())
    with pytest.raises(TypeError):
        encode(np.array([object()], dtype=object))
    # a record naming a type outside the project's result types is refused, not imported
    rec = tmp_path / "r.json"
    for bad in ({"__dataclass__": "os.system", "fields": {}}, {"__object__": "subprocess.Popen", "state": {}},
                {"__dataclass__": "ident.outputs.OutputDir", "fields": {}},
                {"__dataclass__": "ident.cli.__main__.Anything", "fields": {}}):
        rec.write_bytes(dumps_record("h", 1, 2).replace(b'"payload": 1', b'"payload": ' + json.dumps(bad).encode()))
        doc = json.loads(rec.read_text())
        doc["payload_sha256"] = __import__("hashlib").sha256(
            json.dumps(bad, sort_keys=True, separators=(",", ":")).encode()).hexdigest()
        rec.write_text(json.dumps(doc))
        got, problem = read_record(rec, "h", 2)
        assert got is None and "not a valid study record" in problem
    assert "ident.cli.__main__" not in sys.modules           # a record never imports a module


def test_record_hash_check(tmp_path):
    p = tmp_path / "r.json"
    p.write_bytes(dumps_record("h1", {"v": 1.25}, 2, {"angles/t.csv": "ab" * 32}))
    got, problem = read_record(p, "h1", 2)
    assert problem is None and got["result"] == {"v": 1.25}
    assert read_record(p, "h2", 2) == (None, None)           # other inputs: silently recomputed
    assert read_record(p, "h1", 2, file_sha="0" * 64)[1] == "its bytes differ from what the study wrote"
    p.write_text(p.read_text().replace("1.25", "1.5"))         # tampered payload, valid JSON
    got, problem = read_record(p, "h1", 2)
    assert got is None and "recorded hash" in problem


def test_planted_pickle_is_never_executed_and_the_study_completes(tiny, clean, tmp_path, capsys):
    out = tmp_path / "out"
    shutil.copytree(clean, out)
    records = out / STATE_DIR / "records"
    marker = tmp_path / "PWNED"
    evil = pickle.dumps(_Payload(marker))
    (records / "calib.pkl").write_bytes(evil)                  # beside calib.json
    (records / "calib.json").write_bytes(evil)                 # and in its place
    fit_records = sorted((records / "fits").glob("*.json"))
    fit_records[0].write_bytes(evil)
    (records / "fits" / "x.pkl").write_bytes(evil)
    rc, doc, err = _study(tiny, out, capsys=capsys)
    assert rc == 0
    assert not marker.exists()
    assert doc["stages"]["calib"]["computed"] == 1
    assert doc["stages"]["fits"]["computed"] == 1 and doc["stages"]["fits"]["reused"] == 3
    lines = [ln for ln in err.splitlines() if "failed its check" in ln]
    assert len(lines) == 2 and any("calib.json" in ln for ln in lines)
    _same_as_clean(out, clean)


def test_an_output_changed_by_another_command_is_recomputed(tiny, clean, tmp_path, capsys):
    out = tmp_path / "out"
    shutil.copytree(clean, out)
    victim = sorted((out / "angles").glob("*.csv"))[1]
    text = victim.read_text().splitlines()
    cells = text[5].split(",")
    cells[1] = repr(float(cells[1]) + 0.01)                    # a plausible, wrong angle
    text[5] = ",".join(cells)
    victim.write_text("\n".join(text) + "\n")                  # written by another program
    (out / "fits" / "fits.json").write_text("{}")
    rc, doc, err = _study(tiny, out, capsys=capsys)
    assert rc == 0
    assert doc["stages"]["mocap"]["computed"] == 1 and doc["stages"]["mocap"]["reused"] == 3
    assert str(victim) in err and "recomputing" in err
    _same_as_clean(out, clean)
    assert (out / "fits" / "fits.json").read_bytes() == (clean / "fits" / "fits.json").read_bytes()


def test_a_file_written_by_another_jointlab_command_is_refused(tiny, clean, tmp_path, capsys):
    out = tmp_path / "out"
    shutil.copytree(clean, out)
    # another command's entry in the output manifest for one of the study's angle files
    man = json.loads((out / MANIFEST).read_text())
    rel = "angles/j5-load0-v50-r1.csv"
    man["files"][rel]["command"] = "mocap"
    (out / MANIFEST).write_text(json.dumps(man))
    before = (out / rel).read_bytes()
    rc, _, err = _study(tiny, out, capsys=capsys)
    assert rc == 2
    lines = err.strip().splitlines()
    assert len(lines) == 1 and str(out / rel) in lines[0] and "`jointlab mocap`" in lines[0]
    assert (out / rel).read_bytes() == before
    # and `jointlab mocap` refuses to overwrite the study's angles
    out2 = tmp_path / "out2"
    shutil.copytree(clean, out2)
    before = _angles(out2)
    rc = main(["mocap", str(tiny), "--out", str(out2), "--trial", "j5-load0-v50-r1"])
    err = capsys.readouterr().err.strip().splitlines()
    assert rc == 2 and len(err) == 1 and "`jointlab study`" in err[0]
    assert _angles(out2) == before


def test_study_keeps_a_users_file_under_fits(tiny, clean, tmp_path, capsys):
    out = tmp_path / "out"
    shutil.copytree(clean, out)
    note = out / "fits" / "my-notes.txt"
    note.write_text("mine\n")
    rc = main(["study", str(tiny), "--out", str(out), "--workers", "1", "--models", "cv,stribeck",
               "--starts", "1", "--no-rrd", "--no-plots", "--quiet"])
    assert rc == 0
    assert note.read_text() == "mine\n"
    assert "stribeck" in (out / "fits" / "fits.json").read_text()
    # a user's file where the study writes one of its own is refused, and kept
    user = out / "fits" / "fits.json"
    man = json.loads((out / MANIFEST).read_text())
    del man["files"]["fits/fits.json"]
    (out / MANIFEST).write_text(json.dumps(man))
    user.write_text("user data\n")
    capsys.readouterr()
    rc = main(["study", str(tiny), "--out", str(out), "--workers", "1", "--starts", "2"] + FAST[:2] + FAST[4:])
    assert rc == 2 and user.read_text() == "user data\n"
    assert str(user) in capsys.readouterr().err


def _spawn_study(camp, out):
    cmd = [sys.executable, "-m", "ident.cli", "study", str(camp), "--out", str(out), "--workers", "2",
           "--models", "cv,stribeck", "--starts", "2", "--no-rrd", "--no-plots", "--quiet"]
    env = dict(os.environ, PYTHONPATH=str(ROOT) + os.pathsep + os.environ.get("PYTHONPATH", ""),
               OPENBLAS_NUM_THREADS="1")
    return subprocess.Popen(cmd, stdout=subprocess.PIPE, stderr=subprocess.PIPE, env=env, cwd=ROOT,
                            start_new_session=True)


def _workers(p, n: int = 2, timeout: float = 300.0) -> list[int]:
    """The pids of ``p``'s child processes once ``n`` exist (the pool has started), waited for
    at most ``timeout`` s (a generous deadline: the condition, not a time, ends the wait;
    every thread's children are read); [] when the study ended first."""
    t0 = time.monotonic()
    while time.monotonic() - t0 < timeout:
        if p.poll() is not None:
            return []
        kids = []
        for task in Path(f"/proc/{p.pid}/task").glob("*"):
            try:
                kids += [int(k) for k in (task / "children").read_text().split()]
            except OSError:
                pass
        if len(kids) >= n:
            return kids
        time.sleep(0.005)
    return []


@pytest.mark.skipif(not Path("/proc/self/task").is_dir(), reason="needs Linux /proc")
@pytest.mark.parametrize("fault", ["kill-worker", "ctrl-c"])
def test_fault_with_two_workers_is_one_line_and_resumes_to_a_clean_run(tiny, tmp_path, fault):
    clean2 = tmp_path / "clean"
    assert main(["study", str(tiny), "--out", str(clean2), "--workers", "1", "--models", "cv,stribeck",
                 "--starts", "2", "--no-rrd", "--no-plots", "--quiet"]) == 0
    out = tmp_path / "out"
    p = _spawn_study(tiny, out)
    kids = _workers(p)
    assert kids, f"the worker pool was never seen (status {p.poll()})"
    if fault == "kill-worker":
        os.kill(kids[0], signal.SIGKILL)
    else:
        os.killpg(p.pid, signal.SIGINT)                     # what a terminal's Ctrl-C does
    try:
        _, err = p.communicate(timeout=600)     # a deadline for a hang, not a timing
    except subprocess.TimeoutExpired:
        for pid in [p.pid, *kids]:
            try:
                os.kill(pid, signal.SIGKILL)
            except OSError:
                pass
        p.communicate()
        raise AssertionError(f"the study did not end after the {fault}")
    err = err.decode().strip().splitlines()
    assert p.returncode == (1 if fault == "kill-worker" else 130), err
    assert len(err) == 1, err
    assert ("worker process" in err[0]) if fault == "kill-worker" else \
        err[0] == "jointlab: interrupted; rerun to resume"
    assert "Traceback" not in "\n".join(err)
    p = _spawn_study(tiny, out)                             # resume, undisturbed
    _, err = p.communicate(timeout=600)
    assert p.returncode == 0, err.decode()
    _same_as_clean(out, clean2)
