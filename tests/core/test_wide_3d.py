"""The 3-D wide stencil (25 points: the compact 19-point one with pair weight a = 0.08 and the
second axis neighbours through ``-(e/4) sum D_a W D_a``, e = 1/4): its stability limit from the
symbol, an exact discrete plane wave, the flux form (the PML's) equal to the stencil, a
symmetric negative semi-definite operator within the bound at the limit for every side kind
(dense eigenvalues), the measured spectrum next to obstacles, and energy conservation in a
closed room with a post and cut cells over thousands of steps (float64)."""

import itertools
import math

import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np
import pytest

from difflattice.lattice import Edges
from difflattice.lattice.coefficients import build_lattice
from difflattice.lattice.grid import make_grid, stability_limit
from difflattice.lattice.kinds import DEFAULT_COURANT_3D_WIDE, VOLUME, WIDE_AXIS_WEIGHT, WIDE_PAIR_WEIGHT
from difflattice.lattice.medium import Medium
from difflattice.lattice.operators import divergence, face_gradient, stencil
from difflattice.lattice.spectrum import spectral_radius
from difflattice.observe.analytic3d import lattice_omega_3d, lattice_symbol_3d, phase_velocity_3d
from difflattice.solver import Sensors, Stepper, run

jax.config.update("jax_enable_x64", True)

LIMIT = stability_limit("3d", "wide")


def _grid(shape, courant=LIMIT):
    return make_grid(
        frequency_hz=40e3,
        cells_per_wavelength=10,
        c_max_m_s=343.0,
        shape=shape,
        courant=courant,
        dtype="float64",
        kind="3d",
        stencil="wide",
    )


def test_limit_from_the_symbol():
    """The limit is 1 / sqrt(max B) over [0, pi]^3: B = sum s + e sum s^2 - 4a sum s_i s_j on a
    fine grid of s in [0, 1]^3 peaks at 2.79 on the body-diagonal checkerboard, never below 0;
    the symbol of the actual operator (applied to plane waves) is -4 B; a speed over the limit is
    refused naming it; 3-D scenes default to it at 0.595."""
    a, e = WIDE_PAIR_WEIGHT, WIDE_AXIS_WEIGHT
    s = np.array(list(itertools.product(np.linspace(0, 1, 41), repeat=3)))
    B = s.sum(1) + e * (s**2).sum(1) - 4 * a * (s[:, 0] * s[:, 1] + s[:, 1] * s[:, 2] + s[:, 0] * s[:, 2])
    assert B.max() == pytest.approx(2.79, abs=1e-12) and B.min() >= 0
    assert LIMIT == pytest.approx(1 / math.sqrt(B.max()), abs=1e-12)
    n = 16  # periodic plane waves on an n^3 grid, read far from the sides of a larger padded window
    lat = build_lattice(_grid((3 * n, 3 * n, 3 * n), courant=0.5), Medium(343.0, 1.2), Edges.all("soft"))
    x = np.stack(np.meshgrid(*[np.arange(3 * n)] * 3, indexing="ij"), -1).astype(float)
    for m in ((1, 0, 0), (2, 3, 0), (5, 5, 5), (8, 8, 8), (3, 7, 2)):
        k = 2 * np.pi * np.asarray(m) / n
        out = np.asarray(stencil(lat, jnp.asarray(np.cos(x @ k))))[n:-n, n:-n, n:-n]
        ref = -4 * lattice_symbol_3d(k, "wide") * np.cos(x @ k)[n:-n, n:-n, n:-n]
        assert np.abs(out - ref).max() < 1e-12
    assert VOLUME.default_stencil == "wide" and VOLUME.default_courant_for("wide") == DEFAULT_COURANT_3D_WIDE < LIMIT
    with pytest.raises(ValueError, match="3-D wide-stencil stability limit 1/sqrt"):
        _grid((6, 6, 6), courant=1.0001 * LIMIT)


def test_discrete_plane_wave_is_exact_and_accurate():
    """A cosine plane wave along a face diagonal with omega from the dispersion relation stays
    exact to round-off; the phase speed at 6 cells/wavelength is within 0.25 % of the medium's on
    axes, face and body diagonals at the default courant (the isotropic stencil: 1.3 %)."""
    n, steps, c = 40, 6, DEFAULT_COURANT_3D_WIDE
    k = 2 * math.pi / 6 * np.array([1.0, 1.0, 0.0]) / math.sqrt(2)
    x = np.stack(np.meshgrid(*[np.arange(n)] * 3, indexing="ij"), -1).astype(float)
    phase = x @ k
    w = float(lattice_omega_3d(k, c, "wide"))
    stepper = Stepper.build(_grid((n, n, n), courant=c), Medium(343.0, 1.2), edges=Edges.all("rigid"))
    st0 = eqx.tree_at(
        lambda s: (s.p, s.p_prev), stepper.init(), (jnp.asarray(np.cos(phase)), jnp.asarray(np.cos(phase + w)))
    )
    res = run(stepper, steps, state=st0)
    inner = slice(2 * steps + 2, n - 2 * steps - 2)
    assert np.abs(np.asarray(res.final.p) - np.cos(phase - w * steps))[inner, inner, inner].max() < 1e-11
    om = 2 * math.pi * c / 6
    errs = [float(phase_velocity_3d(om, c, d, stencil="wide")) / c - 1 for d in ((1, 0, 0), (1, 1, 0), (1, 1, 1))]
    assert max(abs(e) for e in errs) < 0.0025


def _shape_and_post():
    shape = (13, 12, 11)
    x, y, z = np.meshgrid(*[np.arange(n) for n in shape], indexing="ij")
    post = ((x - 6) ** 2 + (y - 6) ** 2 < 9) | ((x > 9) & (y < 4) & (z < 6))
    return shape, post, (x, y, z)


SIDES = {
    "rigid": Edges.all("rigid"),
    "soft": Edges.all("soft"),
    "mixed": Edges(x_lo="rigid", x_hi="soft", y_lo="soft", y_hi="rigid", z_lo="rigid", z_hi="pml", thickness_cells=2),
}


@pytest.mark.parametrize("sides", list(SIDES))
@pytest.mark.parametrize("obstacles", ["air", "post", "cut_cells", "density"])
def test_flux_form_equals_the_stencil(sides, obstacles):
    """The face values (`face_gradient`, the split-field PML's) give the stencil by their
    divergence, to rounding, for every side kind, a post, fractional cut cells and a density
    contrast: the layer and the interior step the same operator where no PML damps."""
    shape = (9, 8, 7)
    x, y, _ = np.meshgrid(*[np.arange(n) for n in shape], indexing="ij")
    rng = np.random.default_rng(5)
    rigid = {
        "post": ((x - 4) ** 2 + (y - 4) ** 2 < 4).astype(float),
        "cut_cells": np.clip(2 * rng.random(shape) - 0.8, 0, 1),
    }.get(obstacles)
    rho = np.where(x > 4, 2.0, 1.2) if obstacles == "density" else 1.2
    med = Medium(343.0, rho, rigid=None if rigid is None else jnp.asarray(rigid))
    lat = build_lattice(_grid(shape, courant=0.5), med, SIDES[sides])
    q = jnp.asarray(np.random.default_rng(3).standard_normal(shape))
    flux = sum(divergence(lat, face_gradient(lat, q, a), a) for a in range(3))
    assert float(jnp.abs(stencil(lat, q) - flux).max()) < 1e-12


@pytest.mark.parametrize("sides", list(SIDES))
def test_operator_is_symmetric_and_within_the_bound(sides):
    """Dense eigenvalues of the actual operator K L at the limit: symmetric, -K L positive
    semi-definite, c^2 rho <= 4 in air with rigid, soft and mixed window sides (the composition
    of the wall-aware second differences is the whole-space operator on the mirrored field);
    with a post and with cut cells symmetric and semi-definite too (their radius is measured at
    build, next test)."""
    small = (6, 5, 4)
    n = math.prod(small)
    x, y, _ = np.meshgrid(*[np.arange(k) for k in small], indexing="ij")
    cut = np.clip(2 * np.random.default_rng(2).random(small) - 1.2, 0, 1)
    for rigid in (None, ((x - 3) ** 2 + (y - 3) ** 2 < 3).astype(float), cut):
        med = Medium(343.0, 1.2) if rigid is None else Medium(343.0, 1.2, rigid=jnp.asarray(rigid))
        lat = build_lattice(_grid(small), med, SIDES[sides])
        mat = np.asarray(jax.vmap(lambda e, lat=lat: stencil(lat, e.reshape(small)).ravel())(jnp.eye(n)))
        assert np.abs(mat - mat.T).max() < 1e-12
        kk = np.broadcast_to(np.asarray(lat.K), small).ravel()
        ev = np.linalg.eigvalsh(-np.sqrt(kk)[:, None] * mat * np.sqrt(kk)[None, :])
        assert ev.min() > -1e-10
        if rigid is None:
            assert ev.max() <= 4.0 * (1 + 1e-12)


def test_spectrum_next_to_obstacles_is_measured():
    """Next to a post and a box (and with cut cells) the build measures rho(-K L): within the
    bound at the default courant (power iteration, 100 iterations, a lower bound converged near
    the bound; random one-cell voxels too: 3.58 at the limit); a thin soft plate, whose doubled
    face conductances enter the axis fourth difference squared (4.09 at the limit, the operator
    compressed to the fluid cells), is refused with the fix."""
    shape, post, (x, y, z) = _shape_and_post()
    cut = np.clip(post + 0.4 * ((x - 2) ** 2 + (z - 8) ** 2 < 3), 0, 1)
    for rigid in (post, cut):
        lat = build_lattice(
            _grid(shape, courant=DEFAULT_COURANT_3D_WIDE),
            Medium(343.0, 1.2, rigid=jnp.asarray(rigid, float)),
            Edges.all("rigid"),
        )
        rho = spectral_radius(lat, shape, iters=100)
        assert 3.6 < rho <= 4.0, rho
    plate = (x == 6) & (y > 2)
    med = Medium(343.0, 1.2, soft=jnp.asarray(plate, float))
    with pytest.raises(ValueError, match="3-D wide stencil .* measured spectral radius .* lower the grid courant"):
        Stepper.build(_grid(shape), med, edges=Edges.all("rigid"))


def _energy(lat, p1, p0):
    """The leapfrog's conserved energy for symmetric L: sum (p1 - p0)^2 / K - p1 . L p0."""
    return float(jnp.sum((p1 - p0) ** 2 / lat.K) - jnp.sum(p1 * stencil(lat, p0)))


def test_closed_room_with_a_post_conserves_energy():
    """float64, 4000 steps at the default courant in a closed room with a post, a box and a
    cut-cell bump: the discrete energy drifts < 1e-10 of itself (round-off)."""
    shape, post, (x, y, z) = _shape_and_post()
    rigid = np.clip(post + 0.4 * ((x - 2) ** 2 + (z - 8) ** 2 < 3), 0, 1)
    stepper = Stepper.build(
        _grid(shape, courant=DEFAULT_COURANT_3D_WIDE),
        Medium(343.0, 1.2, rigid=jnp.asarray(rigid, float)),
        edges=Edges.all("rigid"),
    )
    p0 = jnp.asarray(np.exp(-((x - 2.0) ** 2 + (y - 10.0) ** 2 + (z - 5.0) ** 2) / 2.0) * (rigid < 1))
    st = eqx.tree_at(lambda s: (s.p, s.p_prev), stepper.init(), (p0, p0))
    e0 = _energy(stepper.lattice, p0, p0)
    res = run(stepper, 4000, state=st, checkpoint=500)
    e1 = _energy(stepper.lattice, res.final.p, res.final.p_prev)
    assert e0 > 0 and abs(e1 - e0) / e0 < 1e-10, (e0, e1)
    assert float(jnp.abs(res.final.p).max()) > 1e-3  # the field is still there (nothing absorbed it)


def test_pml_absorbs_a_plane_pulse():
    """A plane pulse along x (rigid y, z sides) into a 12-cell x_hi PML: the split-field layer
    steps the wide stencil's flux form (face values reaching two cells) and reflects less than its
    design reflection pml_r0 = 1e-8 (-160 dB continuum, graded profile; the discrete layer's floor
    is higher) plus the discretisation's: below -100 dB (measured -128 dB; isotropic and
    seven-point: -127 dB in the same setup)."""
    n, c = 300, DEFAULT_COURANT_3D_WIDE
    g = make_grid(
        frequency_hz=40e3,
        cells_per_wavelength=6,
        c_max_m_s=343.0,
        shape=(n, 6, 6),
        courant=c,
        dtype="float64",
        kind="3d",
        stencil="wide",
    )
    x = np.arange(n)[:, None, None] * np.ones((1, 6, 6))
    p0, pm = (np.exp(-((((x + d) - 200.0) / 4.0) ** 2)) for d in (0.0, c))  # moving towards +x
    edges = Edges(x_lo="rigid", x_hi="pml", y_lo="rigid", y_hi="rigid", z_lo="rigid", z_hi="rigid", thickness_cells=12)
    stepper = Stepper.build(g, Medium(343.0, 1.2), sensors=Sensors(probes=[(220, 3, 3)]), edges=edges)
    st = eqx.tree_at(lambda s: (s.p, s.p_prev), stepper.init(), (jnp.asarray(p0), jnp.asarray(pm)))
    rec = np.abs(np.asarray(run(stepper, int(300 / c), state=st).probes)[:, 0])
    t_back = int((20 + 2 * (n - 220 - 12) - 30) / c)  # the layer's echo; the x_lo one comes after the end
    incident, reflected = rec[: int(35 / c)].max(), rec[t_back:].max()
    assert incident > 0.9 and 20 * np.log10(reflected / incident) < -100


def test_gradient_through_cut_cells_matches_finite_differences():
    """The wide stencil stays differentiable next to obstacles (its axis rows are formed from the
    traced face conductances at build): d(probe energy)/d(cut-cell fraction) by autodiff equals
    the central finite difference (float64, 1e-6 relative). Traced obstacles cannot have their
    spectrum measured, so the bound for any conductances, 1/sqrt(3 (1 + e)) = 0.516, applies:
    at the default courant such a run is refused naming it."""
    from difflattice.solver import simulate
    from difflattice.solver.sources import PointSources, ToneBurst

    shape = (9, 8, 8)
    g = _grid(shape, courant=0.5)
    x, y, _ = np.meshgrid(*[np.arange(n) for n in shape], indexing="ij")
    bump = jnp.asarray(((x - 6) ** 2 + (y - 4) ** 2 < 4).astype(float))
    src = PointSources(cells=np.array([[2, 4, 4]]), signal=ToneBurst(40e3, 2), weights=jnp.ones(1), lags_s=jnp.zeros(1))
    sens = Sensors(probes=[(4, 6, 4)])

    def energy(frac):
        med = Medium(343.0, 1.2, rigid=frac * bump)
        res = simulate(g, med, src, sens, n_steps=25, edges=Edges.all("rigid"), preflight="off")
        return jnp.sum(res.probes**2)

    frac, h = 0.6, 1e-5
    grad = float(jax.grad(energy)(frac))
    energy_jit = jax.jit(energy)  # one program for both evaluations (the maps traced, as under grad)
    fd = (float(energy_jit(frac + h)) - float(energy_jit(frac - h))) / (2 * h)
    assert abs(grad) > 0 and grad == pytest.approx(fd, rel=1e-6)
    g = _grid(shape, courant=DEFAULT_COURANT_3D_WIDE)
    with pytest.raises(ValueError, match="wide stencil's bound for obstacles .*traced maps"):
        jax.grad(energy)(frac)
