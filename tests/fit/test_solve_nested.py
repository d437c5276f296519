"""A fit solved in a richer family it nests in (`fit(..., solve_in=...)`, one more basis function
held at zero) is the same fit: the optimum, its errors and its budget agree with the fit solved in
its own family to the solver's convergence, and the richer family's refit then runs on the
programs that solve compiled (one model structure where there were two)."""

import dataclasses
import logging

import jax
import numpy as np
import pytest

from difflattice.fit.families import shared_family
from difflattice.fit.quantities import _quantities_and_jacobian, quantities_and_jacobian
from difflattice.fit.solve import FitOptions, fit, physical_vector

from ._emulated import data, spec, transfer

CPW = 12.0


@pytest.fixture(scope="module")
def case():
    T = transfer(CPW)
    lobe, wave, _ = data(T, sig_db=0.05, sig_deg=0.1)
    s = spec(T)
    richer = dataclasses.replace(s, n_basis=s.n_basis + 1)
    own = fit(s, T, lobe, wave, FitOptions())
    nested = fit(s, T, lobe, wave, FitOptions(), solve_in=richer)
    return T, lobe, wave, s, richer, own, nested


def test_same_optimum_and_errors(case):
    _, _, _, s, richer, own, nested = case
    assert own.converged and nested.converged
    assert nested.spec == s and nested.solved_in == richer and own.solved_in is None
    assert nested.raw_labels == own.raw_labels  # the extra coefficients are not the nominal fit's
    # The two solves take the same steps up to rounding; the stopping rule (steps that move the
    # residuals by <= rtol_step = 0.05 standard errors) may end them one step apart, so the optima
    # agree to a small fraction of a standard error, and the costs to the rtol_cost (1e-6) test.
    a, labels = physical_vector(s, own.params)
    b, _ = physical_vector(s, nested.params)
    se = np.asarray([own.stderr[k] for k in labels])
    assert np.all(np.abs(np.asarray(b) - np.asarray(a)) <= 0.05 * se + 1e-12), labels
    np.testing.assert_allclose([nested.stderr[k] for k in labels], se, rtol=1e-3)
    assert nested.cost == pytest.approx(own.cost, rel=1e-6)
    assert nested.chi2_reduced == pytest.approx(own.chi2_reduced, rel=1e-6)
    # the covariance is the nominal family's (the extra columns dropped, not a rank-deficient one)
    assert nested.covariance_raw.shape == own.covariance_raw.shape
    assert not nested.rank_deficient
    np.testing.assert_allclose(nested.covariance_raw, own.covariance_raw, rtol=1e-3, atol=1e-12)


def test_quantities_through_the_richer_family(case):
    _, _, _, s, richer, own, nested = case
    v, names, units, G = quantities_and_jacobian(s, nested.params, richer)
    v0, names0, units0, G0 = _quantities_and_jacobian(s, nested.params)
    assert names == list(names0) and units == list(units0)
    np.testing.assert_allclose(v, np.asarray(v0), rtol=1e-12, atol=1e-12)
    np.testing.assert_allclose(G, np.asarray(G0), rtol=1e-10, atol=1e-12)


def test_refit_in_the_richer_family_compiles_no_solver_program(case, caplog):
    T, lobe, wave, s, richer, _, nested = case
    start = s.pad_params(nested.params, richer)
    with caplog.at_level(logging.WARNING), jax.log_compiles(True):
        r = fit(richer, T, lobe, wave, FitOptions(), params0=start)
    compiled = [m for m in caplog.messages if "Compiling" in m]
    solver = [m for m in compiled if any(n in m for n in ("_step", "_init_state", "_residuals", "_jacobian"))]
    assert r.converged
    assert not solver, solver[:3]


def test_shared_family_is_the_budget_refit():
    s = spec(transfer(CPW))
    o = FitOptions()
    assert shared_family(s, o) == dataclasses.replace(s, n_basis=s.n_basis + 1)  # the default families
    assert shared_family(s, o, ["free"]) is None  # a per-cell family does not nest
    assert shared_family(dataclasses.replace(s, weights="uniform", lags="uniform"), o) is None
    with pytest.raises(ValueError, match="solve_in must be the model with more basis functions"):
        T = transfer(CPW)
        lobe, wave, _ = data(T)
        fit(s, T, lobe, wave, o, solve_in=dataclasses.replace(s, n_basis=s.n_basis - 1))
