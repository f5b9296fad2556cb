"""The gap diagnosis's power from samples (issue 25): the HAC loss-differential test (size under
autocorrelated nulls, power on a shifted mean, the Newey-West variance against an AR(1)'s known
long-run variance). Single records of the independent foreign world: tests/test_gap_foreign.py."""

import numpy as np
import pytest

from ident.gap.engine import loss_differential_test, newey_west_lrv


def _ar1(rng, n, rho):
    e = rng.normal(size=n)
    x = np.empty(n)
    x[0] = e[0] / np.sqrt(1 - rho ** 2)
    for i in range(1, n):   # the generator, not the estimator
        x[i] = rho * x[i - 1] + e[i]
    return x


@pytest.mark.parametrize("rho", [0.0, 0.5])
def test_loss_differential_test_holds_its_size_under_autocorrelation(rho):
    rng = np.random.default_rng(3)
    p = np.array([loss_differential_test(_ar1(rng, 300, rho))[0] for _ in range(400)])
    assert 0.02 <= np.mean(p < 0.05) <= 0.09, np.mean(p < 0.05)
    # a naive iid t-test on the same series would reject far more often when rho = 0.5
    if rho:
        from scipy.stats import ttest_1samp
        naive = np.array([ttest_1samp(_ar1(rng, 300, rho), 0, alternative="greater").pvalue for _ in range(400)])
        assert np.mean(naive < 0.05) > 0.12


def test_loss_differential_test_has_power_and_nw_variance_is_right():
    rng = np.random.default_rng(5)
    assert loss_differential_test(0.4 + _ar1(rng, 300, 0.3))[0] < 1e-3
    assert loss_differential_test(-0.4 + _ar1(rng, 300, 0.3))[0] > 0.5
    # long-run variance of an AR(1) with unit innovations: 1 / (1 - rho)^2
    x = _ar1(np.random.default_rng(1), 200000, 0.6)
    lrv, m = newey_west_lrv(x)
    assert lrv == pytest.approx(1 / 0.4 ** 2, rel=0.1) and m > 5
