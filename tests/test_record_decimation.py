"""Decimation of long records (ident.model.record, docs/long-records.md): the anti-alias cut-off
from the friction bandwidth, no aliasing, the motion kept, short records untouched."""
from types import SimpleNamespace

import numpy as np
import pytest

from mocap.io.errors import InputError
from mocap.io.robotlog import RobotLog
from ident.model.record import AUTO_DECIMATE_SAMPLES, RecordSettings, prepare_record

FS = 1000.0


def _log(T, f_motion=0.5, seed=0):
    """One joint: a sine of ``f_motion`` Hz; the torque a slow sine, a 180 Hz tone (which a
    decimation without anti-alias filter folds onto a low frequency) and white noise."""
    rng = np.random.default_rng(seed)
    t = np.arange(T) / FS
    q = 0.4 * np.sin(2 * np.pi * f_motion * t)
    slow = 2.0 * np.cos(2 * np.pi * f_motion * t)
    tau = slow + 0.5 * np.sin(2 * np.pi * 180.0 * t) + 0.05 * rng.standard_normal(T)
    return RobotLog(t, q[:, None], tau[:, None], {}, None), slow


TRIAL = SimpleNamespace(id="rec", joints=(1,))


def test_long_record_is_decimated_with_an_anti_alias_filter():
    T = AUTO_DECIMATE_SAMPLES + 50_000
    log, slow = _log(T)
    rec = prepare_record(log, TRIAL, 1)
    dec = rec.preprocessing["decimation"]
    # velocity band of a 0.5 Hz sine: 0.5 Hz (Welch resolution ~0.03 Hz); 10 harmonics -> 5 Hz,
    # below the 10 Hz floor: cut-off 10 Hz, new rate >= 25 Hz, the largest integer factor
    assert dec["velocity_bandwidth_hz"] == pytest.approx(0.5, abs=0.05)
    assert dec["cutoff_hz"] == 10.0
    assert dec["factor"] == 40 and dec["rate_hz"] == pytest.approx(25.0)
    assert rec.t.size == -(-T // 40)
    np.testing.assert_allclose(np.diff(rec.t), 0.04, rtol=1e-9)
    assert any(s.startswith("decimated by 40") for s in rec.preprocessing["steps"])
    # the 180 Hz tone would alias to |180 - 7 x 25| = 5 Hz; filtered it is gone, and the noise
    # is averaged down: what is left is the slow torque within a small fraction of the tone
    inner = slice(50, -50)                      # the filter's end transients
    err = rec.tau[inner, 0] - slow[::40][inner]
    assert np.sqrt(np.mean(err ** 2)) < 0.02
    np.testing.assert_allclose(rec.q[inner, 0], 0.4 * np.sin(2 * np.pi * 0.5 * rec.t[inner]), atol=2e-3)
    np.testing.assert_allclose(rec.qd[inner, 0], 0.4 * np.pi * np.cos(np.pi * rec.t[inner]), atol=2e-2)


def test_plain_subsampling_would_alias():
    """The check above can fail: every 40th sample without the filter keeps the tone."""
    T = AUTO_DECIMATE_SAMPLES + 50_000
    log, slow = _log(T)
    err = log.tau[::40, 0] - slow[::40]
    assert np.sqrt(np.mean(err ** 2)) > 0.2


def test_faster_motion_raises_the_cutoff_and_explicit_rate():
    T = AUTO_DECIMATE_SAMPLES + 10_000
    log, _ = _log(T, f_motion=3.0)
    dec = prepare_record(log, TRIAL, 1).preprocessing["decimation"]
    assert dec["cutoff_hz"] == pytest.approx(10 * dec["velocity_bandwidth_hz"])
    assert dec["cutoff_hz"] == pytest.approx(30.0, rel=0.05)
    assert dec["factor"] == int(FS // (2.5 * dec["cutoff_hz"]))
    rec = prepare_record(log, TRIAL, 1, settings=RecordSettings(decimate=100.0))
    assert rec.preprocessing["decimation"]["factor"] == 10 and rec.t.size == -(-T // 10)


def test_short_records_and_never_are_untouched():
    log, _ = _log(20_000)
    a = prepare_record(log, TRIAL, 1)
    b = prepare_record(log, TRIAL, 1, settings=RecordSettings(decimate="never"))
    assert a.preprocessing["decimation"]["factor"] == 1 and a.t.size == 20_000
    np.testing.assert_array_equal(a.qd, b.qd)
    np.testing.assert_array_equal(a.tau, b.tau)
    with pytest.raises(InputError, match="decimate"):
        RecordSettings(decimate="often")
