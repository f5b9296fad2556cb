"""A study stopped from outside never leaves anything behind that blocks the next one (issue
45): SIGKILL or SIGTERM of the main ``jointlab study --workers 2`` process leaves no pool
worker alive and a resume completes; SIGTERM is one line and exit 143; a lock whose owner is
gone is taken over with one line; Ctrl-C while the modules load is one line and exit 130; a
damaged study manifest or record means recompute with one line; progress bars only on a
terminal; a marker-less multi-joint study says what ran.

Every wait here is on an observable condition (a process exists, a line was printed, a process
is gone) with a generous deadline, never on a sleep: the tests hold on a loaded machine."""
from __future__ import annotations

import json
import os
import signal
import socket
import subprocess
import sys
import time
from pathlib import Path

import pytest

from ident.cli.main import main
from ident.study.records import dumps_record
from ident.study.study import CACHE_VERSION, MANIFEST_NAME, STATE_DIR

ROOT = Path(__file__).resolve().parents[1]
FAST = ["--models", "cv", "--starts", "1", "--no-rrd", "--no-plots", "--quiet"]
POOL = ["--models", "cv,stribeck", "--starts", "2", "--no-rrd", "--no-plots", "--quiet"]
#: the longest any one condition is waited for (only reached on a hang or a very loaded machine)
DEADLINE = 300.0
LINUX_PROC = Path("/proc/self/task").is_dir()


@pytest.fixture(scope="module")
def tiny(tmp_path_factory):
    """A 4-trial synthetic campaign with [[calib]] sweeps (PA10 joint 5)."""
    camp = tmp_path_factory.mktemp("camp") / "tiny"
    assert main(["synth", str(camp), "--reps", "2", "--duration", "6", "--vmax", "0.5,1.0",
                 "--loads", "0", "--seed", "5", "--quiet"]) == 0
    return camp


@pytest.fixture(scope="module")
def clean(tiny, tmp_path_factory):
    """An uninterrupted serial study with the pool tests' settings: what a resume must equal."""
    out = tmp_path_factory.mktemp("clean") / "out"
    assert main(["study", str(tiny), "--out", str(out), "--workers", "1"] + POOL) == 0
    return out


def _env() -> dict:
    return dict(os.environ, PYTHONPATH=str(ROOT) + os.pathsep + os.environ.get("PYTHONPATH", ""),
                OPENBLAS_NUM_THREADS="1")


def _spawn(args, **kw):
    return subprocess.Popen([sys.executable, "-m", "ident.cli", *map(str, args)], stdout=subprocess.PIPE,
                            stderr=subprocess.PIPE, env=_env(), cwd=ROOT, start_new_session=True, **kw)


def _children(pid: int) -> list[int]:
    """The child processes of every thread of ``pid`` (empty once it is gone)."""
    kids = []
    for task in Path(f"/proc/{pid}/task").glob("*"):
        try:
            kids += [int(k) for k in (task / "children").read_text().split()]
        except OSError:
            pass
    return kids


def _gone(pid: int) -> bool:
    """No such process, or a zombie (dead, waiting to be reaped by whoever adopted it)."""
    try:
        raw = Path(f"/proc/{pid}/stat").read_bytes()
    except OSError:
        return True
    return raw[raw.rindex(b")") + 2:].split()[0] in (b"Z", b"X")


def _until(cond, what: str, deadline: float = DEADLINE, step: float = 0.01):
    t0 = time.monotonic()
    while time.monotonic() - t0 < deadline:
        v = cond()
        if v:
            return v
        time.sleep(step)
    raise AssertionError(f"{what}: not within {deadline:.0f} s")


def _kill_all(pids) -> None:
    """Clean-up after a failed check: the processes this test started (by pid)."""
    for pid in pids:
        try:
            os.kill(pid, signal.SIGKILL)
        except OSError:
            pass


def _params(out: Path) -> dict:
    doc = json.loads((out / "fits" / "fits.json").read_text())["trials"]
    return {(t, j, m): e["params"] for t, js in doc.items() for j, ms in js.items() for m, e in ms.items()}


def _pool_started(p) -> list[int]:
    """Wait until ``p`` runs its two pool workers; their pids (fails when the study ended
    first)."""
    def two():
        if p.poll() is not None:
            raise AssertionError(f"the study ended (status {p.returncode}) before its pool was seen: "
                                 f"{p.stderr.read().decode()[-2000:]}")
        kids = _children(p.pid)
        return kids if len(kids) >= 2 else None
    return _until(two, "the worker pool never started", step=0.005)


# ---------------------------------------------------------------------------------------------
@pytest.mark.skipif(not LINUX_PROC, reason="needs Linux /proc to see the worker processes")
@pytest.mark.parametrize("sig", ["SIGKILL", "SIGTERM"])
def test_killed_study_leaves_no_worker_and_a_resume_completes(tiny, clean, tmp_path, sig):
    out = tmp_path / "out"
    p = _spawn(["study", tiny, "--out", out, "--workers", "2", *POOL])
    kids = []
    try:
        kids = _pool_started(p)
        os.kill(p.pid, getattr(signal, sig))               # the main process only, as a scheduler does
        _, err = p.communicate(timeout=DEADLINE)
        err = err.decode().strip().splitlines()
        if sig == "SIGTERM":
            assert p.returncode == 143, err
            assert err == ["jointlab: terminated (SIGTERM); rerun to resume"], err
        else:
            assert p.returncode == -signal.SIGKILL
        _until(lambda: all(_gone(k) for k in kids), f"pool workers {kids} outlived the study", 60.0)
        r = _spawn(["study", tiny, "--out", out, "--workers", "2", *POOL])   # resume, undisturbed
        try:
            _, err = r.communicate(timeout=DEADLINE)
        except subprocess.TimeoutExpired:
            _kill_all([r.pid, *_children(r.pid)])
            raise AssertionError("the resume never finished (a lock held by a left-over worker?)")
        assert r.returncode == 0, err.decode()
        assert "Traceback" not in err.decode()
        assert _params(out) == _params(clean)
    finally:
        _kill_all([k for k in kids if not _gone(k)] + ([p.pid] if p.poll() is None else []))


def _holder(lock: Path, owner_line: str | None):
    """A process that holds ``lock`` (flock) until killed, as a worker that outlived its study
    would; ``owner_line``: what it writes into the lock file (None: its own pid and host)."""
    code = ("import fcntl, os, socket, sys, time\n"
            "f = open(sys.argv[1], 'a+')\n"
            "fcntl.flock(f, fcntl.LOCK_EX)\n"
            "line = sys.argv[2] if len(sys.argv) > 2 else f'{os.getpid()} {socket.gethostname()} -\\n'\n"
            "f.seek(0); f.truncate(); f.write(line); f.flush()\n"
            "print('held', flush=True)\n"
            "time.sleep(3600)\n")
    args = [sys.executable, "-c", code, str(lock)] + ([owner_line] if owner_line else [])
    h = subprocess.Popen(args, stdout=subprocess.PIPE, stderr=subprocess.DEVNULL)
    assert _readline(h.stdout).strip() == b"held"
    return h


def _stop(h) -> None:
    if h.poll() is None:
        h.kill()
    h.wait()
    h.stdout.close()


def _readline(pipe, deadline: float = DEADLINE) -> bytes:
    """The next line of ``pipe``, waited for at most ``deadline`` seconds."""
    import select

    ready, _, _ = select.select([pipe], [], [], deadline)
    if not ready:
        raise AssertionError(f"no line within {deadline:.0f} s")
    return pipe.readline()


def _dead_pid() -> int:
    p = subprocess.Popen([sys.executable, "-c", "pass"])
    p.wait()
    return p.pid


@pytest.mark.skipif(not hasattr(os, "fork"), reason="flock locks are POSIX")
def test_a_lock_whose_owner_is_gone_is_taken_over_with_one_line(tiny, tmp_path):
    out = tmp_path / "out"
    (out / STATE_DIR).mkdir(parents=True)
    lock = out / STATE_DIR / "lock"
    h = _holder(lock, f"{_dead_pid()} {socket.gethostname()} -\n")   # its owner is gone
    try:
        r = _spawn(["study", tiny, "--out", out, "--workers", "1", *FAST])
        try:
            _, err = r.communicate(timeout=DEADLINE)
        except subprocess.TimeoutExpired:
            _kill_all([r.pid])
            raise AssertionError("the study waited for a lock whose owner is gone")
        err = err.decode()
        assert r.returncode == 0, err
        took = [ln for ln in err.splitlines() if "taking it over" in ln]
        assert len(took) == 1 and str(out) in took[0], err
        assert "waiting" not in err and "Traceback" not in err
    finally:
        _stop(h)


@pytest.mark.skipif(not hasattr(os, "fork"), reason="flock locks are POSIX")
def test_a_lock_whose_owner_runs_is_waited_for(tiny, tmp_path):
    out = tmp_path / "out"
    (out / STATE_DIR).mkdir(parents=True)
    lock = out / STATE_DIR / "lock"
    h = _holder(lock, None)               # alive: its own pid
    r = _spawn(["study", tiny, "--out", out, "--workers", "1", *FAST])
    try:
        line = _readline(r.stderr)
        assert b"another command is writing" in line and b"waiting for it" in line, line
        assert r.poll() is None
        _stop(h)
        _, err = r.communicate(timeout=DEADLINE)
        assert r.returncode == 0, err.decode()
        assert "taking it over" not in err.decode()
    finally:
        _stop(h)
        if r.poll() is None:
            _kill_all([r.pid])
            r.communicate()


# ---------------------------------------------------------------------------------------------
_INTERRUPT_AT = """
import os, signal, sys
class Hook:
    def find_spec(self, name, path=None, target=None):
        if name == {module!r}:
            sys.meta_path.remove(self)
            os.kill(os.getpid(), signal.SIGINT)
        return None
sys.meta_path.insert(0, Hook())
sys.argv = ["jointlab", "study", {camp!r}, "--out", {out!r}, "--workers", "1", "--quiet"]
from ident.cli import main          # the console script's two lines
sys.exit(main())
"""


@pytest.mark.parametrize("module", ["mocap.io.errors", "numpy", "ident.outputs", "ident.study.executor",
                                    "ident.cli.commands.study", "ident.study.study"])
def test_ctrl_c_while_the_modules_load_is_one_line(tiny, tmp_path, module):
    """A Ctrl-C delivered exactly when ``module`` is first imported (an import hook sends it:
    no timing involved), from the console script's start to the study's own imports."""
    code = _INTERRUPT_AT.format(module=module, camp=str(tiny), out=str(tmp_path / "out"))
    r = subprocess.run([sys.executable, "-c", code], capture_output=True, env=_env(), cwd=ROOT,
                       timeout=DEADLINE)
    err = r.stderr.decode().strip().splitlines()
    assert r.returncode == 130, err
    assert err == ["jointlab: interrupted; rerun to resume"], err


# ---------------------------------------------------------------------------------------------
@pytest.fixture(scope="module")
def studied(tiny, tmp_path_factory):
    """A finished serial study of ``tiny`` (each test below damages a copy of it)."""
    out = tmp_path_factory.mktemp("studied") / "out"
    assert main(["study", str(tiny), "--out", str(out), "--workers", "1"] + FAST) == 0
    return out


def _copy(studied, tmp_path) -> Path:
    import shutil

    out = tmp_path / "out"
    shutil.copytree(studied, out, symlinks=True)
    return out


def _run_study(tiny, out, capsys):
    capsys.readouterr()
    rc = main(["study", str(tiny), "--out", str(out), "--workers", "1"] + FAST)
    return rc, capsys.readouterr().err


@pytest.mark.parametrize("damage", ["not-utf8", "truncated", "a-list", "stage-a-string",
                                    "records-a-list", "record-sha-a-number", "empty"])
def test_a_damaged_study_manifest_means_recompute_with_one_line(tiny, studied, tmp_path, capsys, damage):
    out = _copy(studied, tmp_path)
    want = _params(studied)
    path = out / MANIFEST_NAME
    raw = path.read_bytes()
    doc = json.loads(raw)
    bad = {"not-utf8": b"\xff\xfe" + raw[2:],
           "truncated": raw[: len(raw) // 2],
           "a-list": b"[1, 2]",
           "stage-a-string": json.dumps({**doc, "stages": {**doc["stages"], "fits": "x"}}).encode(),
           "records-a-list": json.dumps({**doc, "records": ["a"]}).encode(),
           "record-sha-a-number": json.dumps({**doc, "records": {k: 1 for k in doc["records"]}}).encode(),
           "empty": b""}[damage]
    path.write_bytes(bad)
    rc, err = _run_study(tiny, out, capsys)
    assert rc == 0, err
    assert "Traceback" not in err
    notes = [ln for ln in err.splitlines() if ln.strip()]
    assert len(notes) == 1 and "study manifest" in notes[0] and "recomput" in notes[0], err
    assert _params(out) == want
    if damage == "not-utf8":
        rc, err = _run_study(tiny, out, capsys)             # repaired: a quiet, clean rerun
        assert rc == 0 and err.strip() == "", err


@pytest.mark.parametrize("damage", ["not-utf8", "truncated", "wrong-type"])
def test_a_damaged_study_record_means_recompute_with_one_line(tiny, studied, tmp_path, capsys, damage):
    out = _copy(studied, tmp_path)
    want = _params(studied)
    records = sorted((out / STATE_DIR / "records" / "fits").glob("*.json"))
    rec = records[0]
    raw = rec.read_bytes()
    if damage == "wrong-type":
        # a well-formed record for the current inputs whose result is not what the stage
        # stores (a list, not a dict); its sha256 dropped from the manifest so that only the
        # result's type can give it away
        doc = json.loads(raw)
        rec.write_bytes(dumps_record(doc["input_hash"], [1, 2, 3], CACHE_VERSION, {}))
        man = json.loads((out / MANIFEST_NAME).read_text())
        man["records"].pop(rec.relative_to(out / STATE_DIR).as_posix())
        (out / MANIFEST_NAME).write_text(json.dumps(man))
    else:
        rec.write_bytes(b"\xff\xfe\x00" + raw[3:] if damage == "not-utf8" else raw[: len(raw) // 3])
    rc, err = _run_study(tiny, out, capsys)
    assert rc == 0, err
    assert "Traceback" not in err
    notes = [ln for ln in err.splitlines() if ln.strip()]
    assert len(notes) == 1 and str(rec) in notes[0] and "recomputing" in notes[0], err
    assert _params(out) == want


def test_an_output_manifest_of_the_wrong_type_is_one_line(tiny, studied, tmp_path, capsys):
    """``.jointlab-outputs.json`` whose file list is not an object: nothing is known to be the
    study's, so its files are refused as foreign (one line, exit 2), never a traceback."""
    from ident.outputs import MANIFEST

    out = _copy(studied, tmp_path)
    (out / MANIFEST).write_text('{"format": 1, "files": [1, 2]}')
    rc, err = _run_study(tiny, out, capsys)
    assert rc == 2 and "Traceback" not in err
    assert len(err.strip().splitlines()) == 1 and "not in the output manifest" in err, err


# ---------------------------------------------------------------------------------------------
class _Stream:
    def __init__(self, tty: bool):
        self.tty, self.text = tty, []

    def isatty(self):
        return self.tty

    def write(self, s):
        self.text.append(s)

    def flush(self):
        pass


def test_progress_bars_only_on_a_terminal(monkeypatch):
    from ident.study.executor import SerialExecutor, progress_bars

    assert progress_bars(True, _Stream(True)) and not progress_bars(True, _Stream(False))
    assert not progress_bars(False, _Stream(True))
    log = _Stream(False)                    # stderr redirected to a log file
    monkeypatch.setattr(sys, "stderr", log)
    assert SerialExecutor(progress=True).map(abs, [-1, -2, -3], "fits") == [1, 2, 3]
    assert "".join(log.text) == ""          # no carriage-return bars in the log
    tty = _Stream(True)
    monkeypatch.setattr(sys, "stderr", tty)
    assert SerialExecutor(progress=True).map(abs, [-1, -2, -3], "fits") == [1, 2, 3]
    assert "fits" in "".join(tty.text) and "\r" in "".join(tty.text)


def test_a_marker_less_multi_joint_study_says_what_ran(tmp_path):
    """The bundled TX40 record (6 joints moving together, no markers): no word of static poses
    that do not exist, and the fits stage names where its trials went."""
    camp = ROOT / "fixtures" / "real" / "tx40"
    r = subprocess.run([sys.executable, "-m", "ident.cli", "study", str(camp), "--out", str(tmp_path / "o"),
                        "--workers", "1", "--models", "cv", "--starts", "1", "--no-rrd", "--no-plots",
                        "--no-diagnosis"], capture_output=True, env=_env(), cwd=ROOT, timeout=DEADLINE)
    out, err = r.stdout.decode(), r.stderr.decode()
    assert r.returncode == 0, err
    assert "static poses" not in out + err
    rows = {ln.split()[0]: ln for ln in out.splitlines() if ln.split()}
    assert "no motion capture" in rows["calib"] and "no camera pose needed" in rows["calib"], rows["calib"]
    assert "rigid-body" in rows["fits"] or "rigidbody/" in rows["fits"], rows["fits"]
    assert "computed   1" in rows["rigidbody"]
    assert "friction fits: 0 trial(s)" not in err
    assert "study: rigid-body identification: 1 multi-joint record(s)" in err, err
