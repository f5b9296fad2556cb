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
