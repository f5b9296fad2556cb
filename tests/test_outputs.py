"""Nothing written outside --out, nothing overwritten that a command did not write (issue 29,
write side): paths from ids and symlinks stay inside --out, a campaign's parent is not an
output folder, a foreign file is refused with one line, OS errors and Ctrl-C end in one line
(exit 2 / 130) with no partial output, --workers is capped, a bad --scheduler is one line."""
from __future__ import annotations

import errno
import hashlib
import json
import os
import shutil
from pathlib import Path

import pytest

from ident.cli.main import main
from ident.outputs import MANIFEST, STAGE_DIR, ForeignFileError, OutputDir
from mocap.io.errors import InputError
from tests_paths import DEMO, set_first_trial_key

ROBOT = DEMO / "robot" / "arm.urdf"


def _digest(folder: Path) -> dict:
    return {str(p.relative_to(folder)): hashlib.sha256(p.read_bytes()).hexdigest()
            for p in sorted(folder.rglob("*")) if p.is_file()}


def _files(folder: Path) -> set:
    return {str(p.relative_to(folder)) for p in folder.rglob("*") if p.is_file()} if folder.exists() else set()


@pytest.fixture()
def camp(tmp_path):
    dst = tmp_path / "camp"
    shutil.copytree(DEMO, dst)
    return dst


def _one_line(capsys) -> str:
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1, err
    assert "Traceback" not in err[0]
    return err[0]


# --- the OutputDir rules ------------------------------------------------------------------------
def test_paths_stay_inside_out(tmp_path):
    od = OutputDir(tmp_path / "o", "test")
    (tmp_path / "elsewhere").mkdir()
    (od.root / "link").symlink_to(tmp_path / "elsewhere")
    (od.root / "inner").mkdir()
    (od.root / "alias").symlink_to(od.root / "inner")
    for bad in ("../x.csv", "angles/../../x.csv", str(tmp_path / "x.csv"), "link/x.csv", MANIFEST,
                f"{STAGE_DIR}/x"):
        with pytest.raises(InputError):
            od.rel(bad)
    assert od.rel("alias/x.csv") == "inner/x.csv"          # a link that stays inside is fine
    assert od.rel("a/./b.csv") == "a/b.csv"
    assert not (tmp_path / "x.csv").exists() and not any((tmp_path / "elsewhere").iterdir())


def test_register_refuse_and_prune(tmp_path):
    a = OutputDir(tmp_path / "o", "alpha")
    a.write("r.txt", "1")
    a.write("r.txt", "2")                                  # its own file: rewritten
    man = json.loads((a.root / MANIFEST).read_text())["files"]
    assert man["r.txt"] == {"sha256": hashlib.sha256(b"2").hexdigest(), "command": "alpha"}
    b = OutputDir(tmp_path / "o", "beta")
    with pytest.raises(ForeignFileError, match="`jointlab alpha`"):
        b.write("r.txt", "3")
    (a.root / "user.txt").write_text("mine")
    with pytest.raises(ForeignFileError, match="not in the output manifest"):
        a.write("user.txt", "x")
    assert (a.root / "r.txt").read_text() == "2" and (a.root / "user.txt").read_text() == "mine"
    # a staged tree: committed file by file; prune drops only the command's own stale files
    st = a.stage()
    (st / "d").mkdir()
    (st / "d" / "one.txt").write_text("1")
    (st / "d" / "two.txt").write_text("2")
    a.commit(st, "")
    (a.root / "d" / "user.txt").write_text("mine")
    st = a.stage()
    (st / "one.txt").write_text("1b")
    a.commit(st, "d", prune=True)
    assert _files(a.root / "d") == {"one.txt", "user.txt"}
    # a foreign file among many: nothing of the staged set is moved
    st = a.stage()
    (st / "new.txt").write_text("n")
    (st / "user.txt").write_text("over")
    with pytest.raises(ForeignFileError):
        a.commit(st, "d")
    assert not (a.root / "d" / "new.txt").exists() and (a.root / "d" / "user.txt").read_text() == "mine"
    a.discard()
    assert not (a.root / STAGE_DIR).exists()


# --- commands ---------------------------------------------------------------------------------
def test_trial_id_that_climbs_out_is_refused(camp, tmp_path, capsys):
    set_first_trial_key(camp / "campaign.toml", "id", '"../../../escaped"')
    before, around = _digest(camp), set(os.listdir(tmp_path))
    out = tmp_path / "a" / "b" / "out"
    for argv in (["mocap", str(camp), "--out", str(out)],
                 ["study", str(camp), "--out", str(out), "--workers", "1", "--quiet", "--no-rrd"]):
        assert main(argv) == 2
        _one_line(capsys)
        assert _digest(camp) == before and set(os.listdir(tmp_path)) == around
        assert not list(tmp_path.rglob("escaped*"))


def test_out_with_a_symlink_to_an_input_never_writes_the_input(camp, tmp_path, capsys):
    before = _digest(camp)
    out = tmp_path / "m"
    out.mkdir()
    (out / "angles").symlink_to(camp / "trials")
    assert main(["mocap", str(camp), "--out", str(out)]) == 2
    assert "leaves the output folder" in _one_line(capsys)
    (out / "angles").unlink()
    (out / "mocap.json").symlink_to(camp / "campaign.toml")
    assert main(["mocap", str(camp), "--out", str(out)]) == 2
    _one_line(capsys)
    assert _digest(camp) == before


@pytest.mark.parametrize("where", ["parent", "grandparent"])
def test_out_around_the_campaign_is_refused(camp, tmp_path, capsys, where):
    out = camp.parent if where == "parent" else camp.parent.parent
    before = _files(out)
    assert main(["fit", str(camp), "--out", str(out), "--models", "cv", "--starts", "1"]) == 2
    assert "contains the input folder" in _one_line(capsys)
    assert _files(out) == before


def test_foreign_files_in_out_are_refused_and_kept(camp, tmp_path, capsys):
    out = tmp_path / "o"
    out.mkdir()
    (out / "fits.json").write_text("my notes\n")
    argv = ["fit", str(camp), "--out", str(out), "--models", "cv", "--starts", "1"]
    assert main(argv) == 2
    line = _one_line(capsys)
    assert str(out / "fits.json") in line and "refusing to overwrite" in line
    assert (out / "fits.json").read_text() == "my notes\n"
    (out / "fits.json").unlink()
    assert main(argv) == 0 and main(argv) == 0               # its own files: a rerun rewrites them
    capsys.readouterr()
    man = json.loads((out / MANIFEST).read_text())["files"]
    assert man["fits.json"]["command"] == "fit"
    assert man["fits.json"]["sha256"] == hashlib.sha256((out / "fits.json").read_bytes()).hexdigest()
    # another command meeting fit's files refuses, naming the file and its writer
    (out / "design.json").write_text("{}")
    man["design.json"] = {"sha256": None, "command": "fit"}
    (out / MANIFEST).write_text(json.dumps({"format": 1, "files": man}))
    assert main(["design", "--robot", str(ROBOT), "--joint", "1", "--out", str(out), "--starts", "1"]) == 2
    assert "`jointlab fit`" in _one_line(capsys)


@pytest.mark.parametrize("code", [errno.EROFS, errno.ENOSPC, errno.EACCES, errno.ENAMETOOLONG])
def test_os_errors_while_writing_are_one_line_and_leave_nothing(tmp_path, capsys, monkeypatch, code):
    import ident.outputs as outputs

    def fail(src, dst):
        raise OSError(code, os.strerror(code), str(dst))

    monkeypatch.setattr(outputs.os, "replace", fail)
    out = tmp_path / "o"
    rc = main(["design", "--robot", str(ROBOT), "--joint", "1", "--out", str(out), "--starts", "1"])
    assert rc == 2
    line = _one_line(capsys)
    assert line.startswith("jointlab: error: ") and str(out) in line
    assert not out.exists() or _files(out) <= {".jointlab-outputs.json", ".jointlab-outputs.lock"}
    assert not (out / "design.json").exists()


def test_a_name_too_long_is_one_line(tmp_path, capsys):
    od = OutputDir(tmp_path / "o", "test")
    with pytest.raises(OSError) as exc:
        od.write("x" * 300 + ".csv", "1")
    assert exc.value.errno == errno.ENAMETOOLONG
    from ident.cli.main import _os_error_line

    assert _os_error_line(exc.value).endswith("file name too long")
    assert _files(od.root) <= {".jointlab-outputs.lock", ".jointlab-outputs.json"}


def test_ctrl_c_anywhere_is_130_with_the_resume_hint(tmp_path, capsys, monkeypatch):
    from ident.excitation import design

    def interrupted(*a, **k):
        raise KeyboardInterrupt

    monkeypatch.setattr(design.ExcitationDesigner, "fit", interrupted)
    out = tmp_path / "o"
    assert main(["design", "--robot", str(ROBOT), "--joint", "1", "--out", str(out)]) == 130
    assert _one_line(capsys) == "jointlab: interrupted; rerun to resume"
    assert not out.exists()


def test_synth_truth_inside_another_campaign_is_refused(camp, tmp_path, capsys):
    before = _digest(camp)
    rc = main(["synth", str(tmp_path / "new"), "--truth", str(camp / "truth"), "--quiet"])
    assert rc == 2
    assert "inside the campaign folder" in _one_line(capsys)
    assert _digest(camp) == before and not (tmp_path / "new").exists()


def test_design_out_inside_any_campaign_is_refused(camp, tmp_path, capsys):
    robot = tmp_path / "robot"
    shutil.copytree(DEMO / "robot", robot)
    before = _digest(camp)
    assert main(["design", "--robot", str(robot / "arm.urdf"), "--joint", "1",
                 "--out", str(camp / "designs")]) == 2
    _one_line(capsys)
    assert _digest(camp) == before


def test_scheduler_that_is_not_an_address_is_one_line(camp, tmp_path, capsys):
    assert main(["study", str(camp), "--out", str(tmp_path / "o"), "--scheduler", "notaurl"]) == 2
    assert "--scheduler" in _one_line(capsys)


def test_workers_are_capped_at_the_cpu_count(camp, tmp_path, capsys):
    import time

    t0 = time.monotonic()
    rc = main(["fit", str(camp), "--out", str(tmp_path / "o"), "--models", "cv", "--starts", "1",
               "--workers", "10000"])
    assert rc == 0 and time.monotonic() - t0 < 120
    err = capsys.readouterr().err
    assert "--workers 10000 capped at the" in err
    for bad in ("0", "-3"):
        assert main(["fit", str(camp), "--out", str(tmp_path / "p"), "--models", "cv",
                     "--workers", bad]) == 2
        assert "--workers" in _one_line(capsys)


@pytest.mark.parametrize("argv", [
    ["study", "{c}", "--out", "{o}", "--workers", "1", "--models", "cv", "--starts", "1", "--no-rrd",
     "--no-plots", "--quiet"],
    ["mocap", "{c}", "--out", "{o}"],
])
def test_disk_full_in_study_and_mocap_is_one_line(camp, tmp_path, capsys, monkeypatch, argv):
    import ident.outputs as outputs

    real = os.replace

    def full(src, dst):
        if STAGE_DIR in str(src) and MANIFEST in str(dst):
            return real(src, dst)                 # the bookkeeping fits; the outputs do not
        raise OSError(errno.ENOSPC, os.strerror(errno.ENOSPC), str(dst))

    monkeypatch.setattr(outputs.os, "replace", full)
    before = _digest(camp)
    out = tmp_path / "o"
    assert main([a.format(c=camp, o=out) for a in argv]) == 2
    line = _one_line(capsys)
    assert "no space left on the device" in line
    assert _digest(camp) == before
    left = {f for f in _files(out) if not f.startswith(".jointlab")}
    assert left == set()                          # no output file, whole or half
