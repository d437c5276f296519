"""A fit's three outcomes (issue 27), each with its exit code: consistent (0), converged but the
model does not describe the data (4: a chi-square or runs-test probability below 0.001, or a
parameter at a bound), not converged (3). Data: the line model's own lobe and wavefront plus
Gaussian noise of the stated sigma (so the model is exact), and the same with 10 % of the lobe
points 20 dB off (the issue's l2 fit that said "successful" at chi2_red 514)."""

from __future__ import annotations

import numpy as np
import pytest

from difflattice.fit.data import LobeData
from difflattice.fit.goodness import runs_test
from difflattice.fit.solve import FitOptions, fit
from difflattice.fit.uncertainty import error_budget
from difflattice.fit.verdict import EXIT_CONSISTENT, EXIT_INADEQUATE, EXIT_NOT_CONVERGED, fit_outcome

from ._emulated import ANG, F, data, spec, transfer


@pytest.fixture(scope="module")
def case():
    T = transfer(12.0)
    lobe, wave, _ = data(T, sig_db=0.2, sig_deg=0.5, seed=3)
    rng = np.random.default_rng(7)
    bad = rng.choice(len(ANG), size=len(ANG) // 10, replace=False)
    level = lobe.level_db.copy()
    level[bad] += 20.0 * rng.choice([-1.0, 1.0], size=len(bad))
    dirty = LobeData(ANG, level, lobe.sigma_db, lobe.range_m, F, 16, 20.0)
    return T, lobe, wave, dirty


def test_exact_model_at_the_stated_noise_is_consistent(case):
    T, lobe, wave, _ = case
    r = fit(spec(T), T, lobe, wave, FitOptions())
    v = fit_outcome(r, error_budget(r, T, lobe, wave, make_transfer=None, model_families=[], symmetries=False))
    assert v["exit_code"] == EXIT_CONSISTENT and v["outcome"] == "consistent", v
    assert "chi2_red" in v["line"] and r.goodness["joint"]["p"] >= 1e-3


def test_outliers_with_l2_are_not_a_description_of_the_data(case):
    T, _, wave, dirty = case
    r = fit(spec(T), T, dirty, wave, FitOptions())
    assert r.converged
    v = fit_outcome(r)
    assert v["exit_code"] == EXIT_INADEQUATE, v
    assert v["line"].startswith("FIT CONVERGED BUT THE MODEL DOES NOT DESCRIBE THE DATA")
    assert "lobe chi2_red" in v["line"] and "Try:" in v["line"]


def test_not_converged_exits_3(case):
    T, lobe, wave, _ = case
    r = fit(spec(T), T, lobe, wave, FitOptions(max_steps=1))
    assert not r.converged
    v = fit_outcome(r)
    assert v["exit_code"] == EXIT_NOT_CONVERGED and v["line"].startswith("FIT DID NOT CONVERGE"), v


def test_runs_test_against_its_distribution():
    """Signs of white noise: the one-sided p of too few runs is ~uniform (its 5 % quantile near
    0.05 over 400 draws, binomial sd 0.011); a smooth residual curve gives p < 1e-6."""
    rng = np.random.default_rng(0)
    ps = np.array([runs_test(rng.normal(size=181))[2] for _ in range(400)])
    assert abs(np.mean(ps < 0.05) - 0.05) < 3 * np.sqrt(0.05 * 0.95 / 400) + 0.01  # + continuity correction
    x = np.linspace(-1, 1, 181)
    assert runs_test(np.sin(3 * np.pi * x) + 0.1 * rng.normal(size=181))[2] < 1e-6


def test_chi2_survival_and_normal_cdf_match_their_closed_forms():
    """The fit's p-values come from scipy.special's incomplete gamma (not scipy.stats, for start-up
    time): against the closed forms Q(chi2 >= x | 2 dof) = exp(-x/2), Q(.. | 1 dof) = erfc(sqrt(x/2))
    and Phi(z) = erfc(-z / sqrt 2) / 2 to rounding."""
    import math

    from difflattice.fit.stats import chi2_sf, normal_cdf

    for x in (0.0, 0.3, 2.0, 17.5, 80.0):
        assert math.isclose(chi2_sf(x, 2), math.exp(-x / 2), rel_tol=1e-12, abs_tol=1e-300)
        assert math.isclose(chi2_sf(x, 1), math.erfc(math.sqrt(x / 2)), rel_tol=1e-10, abs_tol=1e-300)
    assert normal_cdf(0.0) == 0.5
    assert math.isclose(normal_cdf(1.0) - normal_cdf(-1.0), 0.6826894921370859, rel_tol=1e-12)
