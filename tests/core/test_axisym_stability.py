"""The axisymmetric (rz) lattice: its stability limit from the spectral bound of the actual
operator, refusals, a point source on the axis against the 3-D free-space Green's function, and
the radial PML (energy conservation in a closed cylinder at the limit and the limit's refusal,
every kind: `test_stability.py`)."""

import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np
import pytest

from difflattice.lattice import Edges
from difflattice.lattice.coefficients import build_lattice
from difflattice.lattice.grid import make_grid, stability_limit
from difflattice.lattice.medium import Medium
from difflattice.lattice.operators import stencil
from difflattice.solver import Stepper, run, simulate
from difflattice.solver.sensors import Sensors
from difflattice.solver.sources import PointSources, ToneBurst

LIMIT = stability_limit("rz")
CLOSED = Edges.axisymmetric("rigid", "rigid", "rigid")


def _grid(shape, courant=LIMIT, dtype="float64", ppw=10):
    return make_grid(
        frequency_hz=40e3,
        cells_per_wavelength=ppw,
        c_max_m_s=343.0,
        shape=shape,
        courant=courant,
        dtype=dtype,
        kind="rz",
    )


def _operator_matrix(lat, shape):
    """The dense matrix of D(P) = K L(P) (lattice units), column by column."""
    n = shape[0] * shape[1]
    basis = jnp.eye(n).reshape(n, *shape)
    cols = jax.vmap(lambda e: lat.K * stencil(lat, e))(basis)
    return np.asarray(cols.reshape(n, n)).T


def _medium(shape, dtype=jnp.float64):
    """Air with a dense slow ring and a rigid body of revolution with cut cells (fractions)."""
    z, r = np.meshgrid(np.arange(shape[0]), np.arange(shape[1]), indexing="ij")
    block = (z > shape[0] // 2) & (r > 2) & (r < 6)
    rigid = np.clip(3.5 - np.hypot(z - 3.0, r + 0.5), 0, 1) * (r < 4)  # a rounded body on the axis
    return Medium(
        jnp.asarray(np.where(block, 250.0, 343.0), dtype),
        jnp.asarray(np.where(block, 4.0, 1.2), dtype),
        rigid=jnp.asarray(rigid, dtype),
    )


@pytest.mark.parametrize("edges", [CLOSED, Edges.axisymmetric("soft", "soft", "soft")], ids=["rigid", "soft"])
def test_spectral_bound_gives_the_limit(edges):
    """Gershgorin on the actual operator: every eigenvalue of -L lies in [0, 8] (the docstring of
    `stability_limit` derives it), so c <= 2 / sqrt(8) = 1/sqrt(2); the eigenvalues are real (L is
    similar to a symmetric matrix); and the bound is sharp: rho(-L) -> 8 with the grid size
    (n = 12: 7.86..7.95, n = 32: > 7.98; Lanczos on the same operator gives 7.9991 at n = 128)."""
    rhos = []
    for n in (12, 32):
        g = _grid((n, n))
        lat = build_lattice(g, Medium(343.0, 1.2), edges)
        D = _operator_matrix(lat, (n, n)) / g.courant**2  # = L
        ev = np.linalg.eigvals(D)
        assert np.abs(ev.imag).max() < 1e-9 * np.abs(ev).max()
        assert ev.real.max() < 1e-9  # -L is positive semidefinite
        rhos.append(-ev.real.min())
    assert max(rhos) <= 8.0 * (1 + 1e-12)
    assert rhos[1] > 7.98 and rhos[1] > rhos[0]
    # with density contrast and cut cells (K / phi, min apertures) the bound still holds at the limit
    g = _grid((12, 10))
    lat = build_lattice(g, _medium((12, 10)), CLOSED)
    ev = np.linalg.eigvals(_operator_matrix(lat, (12, 10)))
    assert np.abs(ev.imag).max() < 1e-8 * np.abs(ev).max()
    assert -ev.real.min() <= 4.0 * (1 + 1e-12)  # c^2 rho(-L) <= 4: the leapfrog's condition


def test_edges_and_models_refused_on_the_wrong_grid():
    g = _grid((8, 8))
    with pytest.raises(ValueError, match="y_lo side is the axis.*Edges.axisymmetric"):
        build_lattice(g, Medium(343.0, 1.2), Edges())  # a PML on the axis
    with pytest.raises(ValueError, match="only for rz grids"):
        build_lattice(
            make_grid(frequency_hz=40e3, cells_per_wavelength=10, c_max_m_s=343.0, shape=(8, 8)),
            Medium(343.0, 1.2),
            CLOSED,
        )
    with pytest.raises(ValueError, match="axis r = 0 of an rz grid is its y_lo side"):
        Edges(x_lo="axis")
    with pytest.raises(ValueError, match="'paper' is not available on an rz grid"):
        build_lattice(g, Medium(343.0, 1.2, boundary_model="paper"), CLOSED)
    with pytest.raises(ValueError, match="grid kind"):
        make_grid(frequency_hz=40e3, cells_per_wavelength=10, c_max_m_s=343.0, shape=(8, 8), kind="xyz")


def test_homogeneous_rz_allocates_no_full_size_coefficients():
    """Air on an rz grid: the metric is two (1, nr) rows, K a scalar, no face arrays."""
    g = _grid((40, 30))
    lat = build_lattice(g, Medium(343.0, 1.2), Edges.axisymmetric(thickness_cells=5))
    assert jnp.ndim(lat.K) == 0 and lat.bx is None and lat.by is None and lat.keep is None
    for a in (lat.metric.hi, lat.metric.lo, lat.metric.volume):
        assert a.shape == (1, 30)
    assert float(lat.metric.lo[0, 0]) == 0.0  # the axis face is closed


def test_point_source_on_the_axis_is_a_3d_point_source():
    """A soft source in the axis cell, PML all round: bounded, and the field is the 3-D free-space
    Green's function. Adding v(n) to one ring cell of volume pi (cells^3, 2 pi x 1/2) is the point
    source q(t) = pi v of p_tt = c^2 lap p + q delta, so p(R, n) = v(n + 1 - R / c) / (4 c^2 R)
    (the one-step lead: the value added at step n + 1 drives the step centred at n). At 20
    cells per wavelength the burst's peak along the axis and at 45 deg agrees with it to the
    lattice's phase error over R (< 0.3 % of a period per wavelength: a ~1 % level change on a
    Hann-windowed peak) and the ring cell's size (O((k / 2)^2 / 6) ~ 1.6 %): 3 % tolerance."""
    jax.config.update("jax_enable_x64", True)
    ppw, L = 20, 12
    n = 130
    g = _grid((n, 70), ppw=ppw, courant=0.7)
    zs = 40
    sig = ToneBurst(g.frequency_hz, 3.0)
    src = PointSources(cells=[(zs, 0)], signal=sig, weights=jnp.ones(1), lags_s=jnp.zeros(1))
    R = np.array([25.0, 50.0, 75.0])
    probes = [(zs + int(r), 0) for r in R] + [(zs + 35, 35)]  # on axis, and 45 deg (R = 49.5)
    res = simulate(
        g, Medium(343.0, 1.2), src, Sensors(probes=probes), n_steps=320, edges=Edges.axisymmetric(thickness_cells=L)
    )
    p = np.asarray(res.probes)
    assert np.all(np.isfinite(p)) and np.abs(p).max() < 1.0
    c = g.courant
    steps = np.arange(1, 321)
    zc = np.array([zs + int(r) + 0.5 for r in R] + [zs + 35.5]) - (zs + 0.5)
    rc = np.array([0.5] * 3 + [35.5])  # ring centres; the source ring is centred on the axis in 3-D
    dist = np.hypot(zc, np.where(rc > 1, rc, 0.0))
    for k in range(4):
        ref = np.asarray(sig((steps + 1 - dist[k] / c) * g.dt_s)) / (4 * c**2 * dist[k])
        assert abs(np.abs(p[:, k]).max() / np.abs(ref).max() - 1) < 0.03, (k, np.abs(p[:, k]).max(), np.abs(ref).max())
    # after the burst has passed every probe the field is gone (no ringing axis cell)
    late = simulate(
        g,
        Medium(343.0, 1.2),
        src,
        Sensors(probes=[(zs, 0), (zs + 5, 0)]),
        n_steps=600,
        edges=Edges.axisymmetric(thickness_cells=L),
    )
    assert np.abs(np.asarray(late.probes)[-50:]).max() < 1e-3 * np.abs(np.asarray(late.probes)).max()


def test_radial_pml_absorbs_oblique_waves():
    """The r_hi PML with the cylindrical correction (`RadialPML`): a burst from the axis meets the
    layer at 45 deg on its way to a probe on the axis. Against a window too wide to reach, the
    reflection is below -80 dB (-97 dB measured; the 2-D layer of the same thickness: about -115
    dB), while the split-field layer without the correction (the ring metric unstretched) reflects
    at -31 dB: the test sees the difference."""
    jax.config.update("jax_enable_x64", True)
    ppw, L, W = 12, 12, 60
    nz, zs = 5 * W, W + L
    n_steps = int(3.0 * W / 0.7)

    def probe(nr, radial=True):
        g = make_grid(
            frequency_hz=50e3,
            cells_per_wavelength=ppw,
            c_max_m_s=343.0,
            shape=(nz, nr),
            courant=0.7,
            dtype="float64",
            kind="rz",
        )
        src = PointSources(cells=[(zs, 0)], signal=ToneBurst(50e3, 3.0), weights=jnp.ones(1), lags_s=jnp.zeros(1))
        st = Stepper.build(
            g,
            Medium(343.0, 1.2),
            src,
            Sensors(probes=[(zs + W, 0)]),
            Edges.axisymmetric("rigid", "rigid", "pml", thickness_cells=L),
        )
        if not radial:
            st = eqx.tree_at(lambda s: s.lattice.pml.radial, st, None, is_leaf=lambda x: x is None)
        return np.asarray(run(st, n_steps).probes)[:, 0]

    ref = probe(W + L + 2 * W)
    level = lambda p: 20 * np.log10(np.abs(p - ref).max() / np.abs(ref).max())
    assert level(probe(W + L)) < -80.0
    assert level(probe(W + L, radial=False)) > -40.0
