"""Robot log CSV (FORMAT.md): reading, validation messages, round trip."""
import numpy as np
import pytest

from mocap.io.errors import InputError
from mocap.io.robotlog import RobotLog, read_robot_log, write_robot_log


def _write(tmp_path, text, name="log.csv"):
    p = tmp_path / name
    p.write_text(text)
    return p


def test_reads_columns_extras_and_gaps(tmp_path):
    p = _write(tmp_path, "time,qm_1,qm_2,tau_1,tau_2,temp_1\n"
                         "10.0,0.1,0.2,1.5,2.5,30\n"
                         "10.005,0.11,,1.6,2.6,30.1\n"
                         "10.010,0.12,0.22,,2.7,30.2\n")
    log = read_robot_log(p)
    assert log.n_samples == 3 and log.n_joints == 2
    np.testing.assert_allclose(log.time, [10.0, 10.005, 10.010])
    assert np.isnan(log.qm[1, 1]) and np.isnan(log.tau[2, 0])
    assert log.qm[2, 1] == pytest.approx(0.22)
    np.testing.assert_allclose(log.extra["temp_1"], [30, 30.1, 30.2])
    assert log.rate_hz == pytest.approx(200.0)


def test_width_follows_robot_and_absent_joints_are_nan(tmp_path):
    p = _write(tmp_path, "time,qm_5,tau_5\n0,1,2\n0.01,1.1,2.1\n")
    log = read_robot_log(p, n_joints=6)
    assert log.qm.shape == (2, 6)
    assert np.all(np.isnan(log.qm[:, :4])) and log.qm[1, 4] == pytest.approx(1.1)


@pytest.mark.parametrize("text, needle, line", [
    ("time,qm_1\n0,1\n0,2\n", "not strictly increasing", 3),
    ("time,qm_1\n0,1\n0.1,abc\n", "non-numeric", 3),
    ("time,qm_1\n0,1\n0.1,2,3\n", "expected 2 cells", 3),
    ("t,qm_1\n0,1\n", "no 'time' column", 1),
])
def test_bad_logs_name_file_and_line(tmp_path, text, needle, line):
    p = _write(tmp_path, text)
    with pytest.raises(InputError) as e:
        read_robot_log(p)
    msg = str(e.value)
    assert needle in msg and str(p) in msg and f"line {line}" in msg


def test_joint_beyond_robot_is_rejected(tmp_path):
    p = _write(tmp_path, "time,qm_7\n0,1\n")
    with pytest.raises(InputError, match="joint 7 but the robot has 6"):
        read_robot_log(p, n_joints=6)


def test_round_trip_and_no_overwrite(tmp_path):
    rng = np.random.default_rng(3)
    t = 5 + np.arange(100) / 200
    qm, tau = rng.normal(size=(100, 3)), rng.normal(size=(100, 3))
    qm[10, 1] = np.nan
    log = RobotLog(t, qm, tau, {"qd_ref_1": rng.normal(size=100)})
    p = write_robot_log(tmp_path / "a.csv", log)
    back = read_robot_log(p, n_joints=3)
    np.testing.assert_allclose(back.qm, qm, rtol=1e-8, equal_nan=True)
    np.testing.assert_allclose(back.tau, tau, rtol=1e-8)
    np.testing.assert_allclose(back.extra["qd_ref_1"], log.extra["qd_ref_1"], rtol=1e-8)
    with pytest.raises(FileExistsError):
        write_robot_log(p, log)


# --- the streaming reader (pyarrow) against the careful parser -------------------------------
from mocap.io import robotlog as rl  # noqa: E402


def _same(a, b):
    np.testing.assert_array_equal(a.time, b.time)
    np.testing.assert_array_equal(a.qm, b.qm)
    np.testing.assert_array_equal(a.tau, b.tau)
    assert list(a.extra) == list(b.extra)
    for k in a.extra:
        np.testing.assert_array_equal(a.extra[k], b.extra[k])
    np.testing.assert_array_equal(a.line_numbers, b.line_numbers)


@pytest.mark.parametrize("text, n_joints", [
    ("time,qm_1,tau_1\n0,1,2\n0.5,1.5,\n1,nan,NaN\n", None),                      # gaps, nan
    ("\ufefftime,qm_2,tau_2,qd_2,temp\r\n0,1,2,3,4\r\n1e-3,-1.5e+2,.5,NAN,7\r\n", 4),  # BOM, CRLF
    ("time,tau_1,qm_1,tau_3\n0,1,2,3\n1,4,5,6", None),                           # no final newline
    ("qm_1,time\n-0,0\n+1.,1\n", None),                                           # time not first
    ("time,qm_1,tau_1\n0, 1,\t2\n1 ,nan ,-3\n", None),                          # spaces, tabs
])
def test_streaming_reader_equals_careful_parser(tmp_path, text, n_joints):
    p = tmp_path / "log.csv"
    p.write_bytes(text.encode())
    fast = rl._read_fast(p, n_joints)
    assert fast is not None
    _same(fast, rl._read_careful(p, n_joints))


@pytest.mark.parametrize("text", [
    "time,qm_1\n0,1\n\n1,2\n",            # blank line (line numbers shift)
    "time,qm_1\n0,\x0b1\n1,2\n",          # a control character
    "time,qm_1\n0,1_0\n1,2\n",            # a number Python reads, pyarrow not
    'time,qm_1\n0,"1"\n1,2\n',            # a quote
    "time,qm_1\n0,1\r1,2\n",              # a lone carriage return
    "time,qm_1\n0,NA\n1,2\n",             # a word
    "time,qm_1\n0,1e999\n1,2\n",          # infinite
    "time,qm_1\n0,1e12\n1,2\n",           # absurd
    "time,qm_1\n1,1\n0,2\n",              # time not increasing
    "time,qm_1\n,1\n1,2\n",               # time missing
    "time,qm_1\n0,1,3\n1,2\n",            # a row too long
    "time,qm_1\n0\n1,2\n",                # a row too short
    "time,qm_1\n",                        # no samples
    "time,qm3\n0,1\n",                    # damaged name
])
def test_streaming_reader_declines_what_the_careful_parser_judges(tmp_path, text):
    p = tmp_path / "log.csv"
    p.write_bytes(text.encode())
    assert rl._read_fast(p, None) is None


def test_streaming_reader_random_logs_and_blocks(tmp_path, monkeypatch):
    """Random well-formed logs in several number formats, read in tiny blocks; the repeated-row
    check in tiny row blocks against the whole-table formula."""
    rng = np.random.default_rng(11)
    monkeypatch.setattr(rl, "_CHUNK", 64)
    monkeypatch.setattr(rl, "_ROW_BLOCK", 7)
    for trial in range(6):
        T, n = int(rng.integers(2, 300)), int(rng.integers(1, 4))
        t = np.cumsum(rng.uniform(0.5, 1.5, T)) * 1e-3
        X = rng.normal(scale=10.0 ** rng.integers(-3, 3), size=(T, 2 * n + 1))
        X[rng.random(X.shape) < 0.05] = np.nan
        rep = rng.random(T) < 0.2
        rep[0] = False
        for i in np.flatnonzero(rep):
            X[i] = X[i - 1]
        fmt = ["%.9g", "%.3e", "%.17g", "%.4f"][trial % 4]
        body = np.char.mod(fmt, np.column_stack([t, X]))
        body[:, 1:][np.isnan(X)] = ["", "nan", "NaN"][trial % 3]
        names = ["time"] + [f"qm_{j + 1}" for j in range(n)] + [f"tau_{j + 1}" for j in range(n)] + ["qd_1"]
        p = tmp_path / f"log{trial}.csv"
        p.write_text(",".join(names) + "\n" + "\n".join(",".join(r) for r in body) + "\n")
        fast = rl._read_fast(p, None)
        assert fast is not None
        slow = rl._read_careful(p, None)
        _same(fast, slow)
        sig = np.column_stack([slow.qm, slow.tau, slow.qd])
        whole = np.concatenate([[False], ((sig[1:] == sig[:-1])
                                          | (np.isnan(sig[1:]) & np.isnan(sig[:-1]))).all(axis=1)])
        np.testing.assert_array_equal(fast.repeated_rows(), whole)
        assert whole[rep].all()


def test_files_from_a_megabyte_on_stream(tmp_path, monkeypatch):
    rng = np.random.default_rng(2)
    T = 30_000
    log = RobotLog(np.arange(T) / 1000.0, rng.normal(size=(T, 3)), rng.normal(size=(T, 3)))
    p = write_robot_log(tmp_path / "big.csv", log)
    assert p.stat().st_size >= rl.STREAM_MIN_BYTES
    slow = rl._read_careful(p, None)

    def refuse(*a):
        raise AssertionError("the careful parser read a well-formed long log")

    monkeypatch.setattr(rl, "_read_careful", refuse)
    _same(read_robot_log(p), slow)


def test_streaming_reader_grows_past_a_short_row_estimate(tmp_path, monkeypatch):
    """Long lines at both ends of the file and short ones in between: the row count estimated
    from the ends is too small, the reader grows its arrays and still reads every row."""
    monkeypatch.setattr(rl, "_CHUNK", 256)
    monkeypatch.setattr(rl, "_TAIL", 256)
    T = 2000
    t = np.arange(T) * 1e-3
    q = np.sin(np.arange(T) * 0.01)
    rows = [f"{tt:.17g},{x:.17g},{-x:.17g}" if (k < 50 or k >= T - 50) else f"{tt:.3f},{x:.1f},{-x:.1f}"
            for k, (tt, x) in enumerate(zip(t, q))]
    p = tmp_path / "log.csv"
    p.write_text("time,qm_1,tau_1\n" + "\n".join(rows) + "\n")
    with open(p, "rb") as fh:
        head = fh.read(rl._CHUNK)
        start = head.find(b"\n") + 1
        assert rl._row_capacity(fh, head[start:], start) < T          # the estimate falls short
    fast = rl._read_fast(p, None)
    assert fast is not None and fast.time.size == T
    _same(fast, rl._read_careful(p, None))
