"""The disc model family (fit.disc) and its independent references, without the lattice.

References: the Rayleigh integral of each ring (fit.transfer_disc, periodic trapezoid in azimuth)
against the emulator's own piston and disc quadrature (capture.groundtruth, Gauss-Legendre:
different code); closed-form ring areas and second moments; forward- against reverse-mode
derivatives and central differences (f64)."""

from __future__ import annotations

import dataclasses
import math

import jax
import jax.numpy as jnp
import numpy as np
import pytest
from jax.flatten_util import ravel_pytree

from difflattice.capture.groundtruth import Disc, Piston, make_transducer
from difflattice.fit.disc import DiscSpec, area_fraction, profile_values, rim_fraction, ring_edges
from difflattice.fit.model import lobe_model_db, wave_model_phase
from difflattice.fit.transfer_disc import rayleigh_disc_transfer, rayleigh_ring_field

F = 50e3
C = 331.3 * math.sqrt(1 + 21 / 273.15)
K = 2 * math.pi * F / C
DR = C / F / 20  # 20 cells per wavelength


def test_rim_fraction_has_exact_area_and_second_moment():
    edges = ring_edges(60, DR)
    A = np.pi * (edges[:, 1] ** 2 - edges[:, 0] ** 2)
    S = 0.5 * np.pi * (edges[:, 1] ** 4 - edges[:, 0] ** 4)
    rim, area = jax.jit(rim_fraction), jax.jit(area_fraction)
    for a in np.r_[np.linspace(0.2, 59.7, 37), 55.0, 55.5] * DR:
        f = np.asarray(rim(jnp.asarray(edges), a))
        if a > DR:
            assert f @ A == pytest.approx(np.pi * a**2, rel=1e-12)
            assert f @ S == pytest.approx(0.5 * np.pi * a**4, rel=1e-12)
        assert np.asarray(area(jnp.asarray(edges), a)) @ A == pytest.approx(np.pi * a**2, rel=1e-12)
    # continuous where the rim crosses a ring edge
    for m in (1, 7, 55):
        lo, hi = (np.asarray(rim(jnp.asarray(edges), m * DR + s)) for s in (-1e-12, 1e-12))
        np.testing.assert_allclose(lo, hi, atol=1e-8)  # a change of 2e-12 m moves a weight by ~1e-8


def test_rayleigh_rings_sum_to_the_emulators_piston():
    # radius on a ring edge: the rings tile the piston exactly; two different quadratures agree
    n, a = 60, 55 * DR
    x = np.linspace(-0.024, 0.024, 13)
    ang = np.array([0.0, 5.0, 17.0, 33.0, 60.0, 89.0])
    T = rayleigh_disc_transfer(
        frequency_hz=F,
        c_m_s=C,
        n_rings=n,
        dr_m=DR,
        lobe_angle_deg=ang,
        lobe_range_m=1.0,
        wave_x_m=x,
        wave_z_m=0.0165,
        rtol=1e-10,
    )
    f = (np.arange(n) < 55).astype(float)
    p = Piston(2 * a, sensitivity_uV=1.0, n_quad=160)
    scale = -1j * K * np.pi * a**2 / (2 * np.pi)  # Piston: S (-i / (pi a^2)) integral; rings: -i k / (2 pi) integral
    np.testing.assert_allclose(T.wave @ f, scale / (-1j) * p.near_field(x, 0.0165, F, C), rtol=1e-9)
    np.testing.assert_allclose(T.lobe @ f, scale / (-1j) * p.at_range(ang, 1.0, F, C), rtol=1e-9)


def test_rayleigh_quadrature_refuses_points_on_the_face():
    with pytest.raises(ValueError, match="face"):
        rayleigh_ring_field(ring_edges(4, DR), [0.5 * DR], [0.0], K)


def _taper_truth():
    w_raw = [math.log(0.5), math.log(0.25 / 0.75)]  # rim weight 0.5 over the outer quarter
    lag_raw = [0.15, 0.05]
    u = np.linspace(0, 1, 801)
    return w_raw, lag_raw, u


def test_disc_ground_truth_matches_rings_of_the_model():
    """The emulator's Disc (continuous profile, Gauss-Legendre between knots) against the model's
    rings (profile sampled at ring centres, rim by moments) through the Rayleigh reference: they
    differ by the model's discretisation, the midpoint rule per ring, O((dr / b)^2) relative to
    the taper's contribution (~1e-3 with the taper over b = 14 cells)."""
    w_raw, lag_raw, u = _taper_truth()
    D = 0.0384
    spec = DiscSpec(n_cells=61, dx_m=DR, frequency_hz=F, weights="rim_taper", lags="smooth", n_basis=2)
    a_model = np.asarray(spec.amplitudes(spec.truth_params(diameter_m=D, w=w_raw, lag=lag_raw)))
    truth = make_transducer(
        {
            "kind": "disc",
            "diameter_m": D,
            "sensitivity_uV": 1.0,
            "r_frac": list(u),
            "weights": list(profile_values("rim_taper", w_raw, u, kind="weights", period_s=1 / F)),
            "lags_s": list(profile_values("smooth", lag_raw, u, kind="lags", period_s=1 / F)),
        }
    )
    assert isinstance(truth, Disc)
    x = np.linspace(0, 0.024, 9)
    ang = np.array([0.0, 4.0, 9.0, 15.0, 30.0])
    T = rayleigh_disc_transfer(
        frequency_hz=F,
        c_m_s=C,
        n_rings=61,
        dr_m=DR,
        lobe_angle_deg=ang,
        lobe_range_m=1.0,
        wave_x_m=x,
        wave_z_m=0.0165,
        rtol=1e-9,
    )
    scale = 1j * (-1j * K * np.pi * (D / 2) ** 2 / (2 * np.pi))
    near, lobe = T.wave @ a_model, T.lobe @ a_model
    ref_near, ref_lobe = scale * truth.near_field(x, 0.0165, F, C), scale * truth.at_range(ang, 1.0, F, C)
    assert np.max(np.abs(near / ref_near - 1)) < 3e-3
    assert np.max(np.abs(np.degrees(np.angle(near / ref_near)))) < 0.1
    assert np.max(np.abs(lobe[:3] / ref_lobe[:3] - 1)) < 3e-3  # main lobe
    # the uniform disc is the piston
    flat = Disc(D, sensitivity_uV=1.0)
    np.testing.assert_allclose(flat.near_field(x, 0.0165, F, C), Piston(D, 1.0).near_field(x, 0.0165, F, C), rtol=1e-9)
    np.testing.assert_allclose(flat.far_field(ang, F, C), Piston(D, 1.0).far_field(ang, F, C), rtol=1e-9, atol=1e-12)


@pytest.mark.parametrize("profile", ["smooth", "rim_taper"])
def test_profile_values_are_the_models_profiles(profile):
    spec = DiscSpec(n_cells=61, dx_m=DR, frequency_hz=F, weights=profile, lags=profile, n_basis=3)
    raw = [0.3, -0.2, 0.1] if profile == "smooth" else [-0.4, -1.0]
    p = spec.truth_params(diameter_m=0.038, w=raw, lag=raw)
    ph = spec.physical(p)
    u = spec.r_m / 0.019
    np.testing.assert_allclose(
        ph["weights_raw"], profile_values(profile, raw, u, kind="weights", period_s=1 / F), rtol=1e-12
    )
    np.testing.assert_allclose(
        ph["lags_s"], profile_values(profile, raw, u, kind="lags", period_s=1 / F), rtol=1e-12, atol=1e-18
    )


def _observables(spec, T):
    def f(params):
        return jnp.concatenate([lobe_model_db(spec, params, T.lobe), wave_model_phase(spec, params, T.wave)])

    return f


@pytest.fixture(scope="module")
def small_transfer():
    return rayleigh_disc_transfer(
        frequency_hz=F,
        c_m_s=C,
        n_rings=40,
        dr_m=DR,
        lobe_angle_deg=np.arange(-60, 61, 10.0),
        lobe_range_m=1.0,
        wave_x_m=np.linspace(-0.012, 0.012, 7),
        wave_z_m=0.01,
        rtol=1e-6,
    )


@pytest.mark.parametrize("weights,lags", [("free", "free"), ("smooth", "smooth"), ("rim_taper", "rim_taper")])
def test_gradients_forward_equals_reverse_and_differences(small_transfer, weights, lags):
    """d(observables)/d(ring weights, lags, radius): forward = reverse mode to 1e-9 (f64), and
    central differences agree to O(h^2) (Taylor: the error falls 4x when h halves)."""
    n, T = 40, small_transfer
    spec = DiscSpec(n_cells=n, dx_m=DR, frequency_hz=F, weights=weights, lags=lags, n_basis=3)
    rng = np.random.default_rng(3)
    p0 = spec.init_params()
    p0 = jax.tree_util.tree_map(lambda v: v + 0.05 * jnp.asarray(rng.standard_normal(np.shape(v))), p0)
    p0 = dataclasses.replace(p0, diam=jnp.asarray(math.log(0.81 / 0.19)))  # radius 32.4 cells: inside a ring
    y0, unravel = ravel_pytree(p0)
    g = _observables(spec, T)
    fy = jax.jit(lambda y: g(unravel(y)))
    jf = np.asarray(jax.jit(jax.jacfwd(fy))(y0))
    jr = np.asarray(jax.jit(jax.jacrev(fy))(y0))
    assert np.all(np.isfinite(jf)) and np.abs(jf).max() > 0
    np.testing.assert_allclose(jf, jr, rtol=1e-9, atol=1e-9 * np.abs(jf).max())
    v = rng.standard_normal(y0.shape)
    d = jf @ v
    errs = []
    for h in (1e-3, 5e-4):
        fd = (np.asarray(fy(y0 + h * v)) - np.asarray(fy(y0 - h * v))) / (2 * h)
        errs.append(np.abs(fd - d).max())
    assert errs[1] < 0.35 * errs[0] or errs[1] < 1e-9 * np.abs(d).max()


def test_radius_gradient_through_the_rim():
    """The diameter's derivative inside a ring is the derivative of the rim weights (moments rim)."""
    spec = DiscSpec(n_cells=40, dx_m=DR, frequency_hz=F)
    edges = jnp.asarray(spec.ring_edges_m)
    a0 = 30.37 * DR
    fwd = jax.jacfwd(lambda a: rim_fraction(edges, a))(a0)
    rev = jax.jacrev(lambda a: rim_fraction(edges, a))(a0)
    np.testing.assert_allclose(fwd, rev, rtol=1e-12, atol=1e-15)
    h = 1e-4 * DR
    fd = (np.asarray(rim_fraction(edges, a0 + h)) - np.asarray(rim_fraction(edges, a0 - h))) / (2 * h)
    np.testing.assert_allclose(fwd, fd, rtol=1e-6, atol=1e-6 * np.abs(fd).max())
    assert np.count_nonzero(np.asarray(fwd)) == 2  # the rim ring and the one inside it


def test_spec_interface_for_the_solver():
    spec = DiscSpec(n_cells=30, dx_m=DR, frequency_hz=F, weights="rim_taper", lags="smooth", n_basis=2)
    p = spec.init_params()
    y, _ = ravel_pytree(p)
    assert len(spec.raw_labels(p)) == y.size
    assert spec.n_cells == 30 and spec.y_m.shape == (30,) and spec.d_max_m == pytest.approx(60 * DR)
    q = spec.symmetries()["time reversal"](dataclasses.replace(p, lag=jnp.array([0.2, -0.1]), phase0=jnp.asarray(0.3)))
    np.testing.assert_allclose(q.lag, [-0.2, 0.1])
    assert float(q.phase0) == pytest.approx(-0.3)
    warm = spec.params_from_profiles(None, np.log(1 + 0.1 * (spec.r_m / 0.009) ** 2), 0.018, p)
    assert set(warm.names()) == set(p.names()) - {"phase0", "gain_db"} | {"phase0", "gain_db"}


@pytest.mark.parametrize(
    "kw,match",
    [
        ({"weights": "tapered"}, "weights"),
        ({"n_cells": 1}, "n_cells"),
        ({"diameter_m": 1.0}, "diameter_m"),
        ({"rim_width_m": -1e-3, "weights": "rim_taper"}, "rim_width_m"),
        ({"rim": "exact"}, "rim"),
        ({"axis": "edge"}, "axis"),
    ],
)
def test_bad_specs_are_refused(kw, match):
    with pytest.raises(ValueError, match=match):
        DiscSpec(**{"n_cells": 30, "dx_m": DR, "frequency_hz": F, **kw})


def test_line_model_names_carry_over():
    """Code written for the line model (a refit at another resolution, another profile family)
    builds disc models with `dataclasses.replace` and the line's names."""
    import dataclasses

    spec = DiscSpec(n_cells=30, dx_m=DR, frequency_hz=F, weights="smooth", lags="smooth")
    finer = dataclasses.replace(spec, n_cells=45, dx_m=DR * 2 / 3, weights="symmetric")
    assert (finer.n_rings, finer.dr_m, finer.weights) == (45, DR * 2 / 3, "free")
    assert finer.d_max_m == pytest.approx(spec.d_max_m)
