"""The 3-D isotropic (19-point, Kowalczyk & van Walstijn's IISO) stencil: its dispersion relation
(an exact discrete plane wave stays exact), the spectral bound of the actual operator behind the
limit sqrt(3)/2 (rigid and soft sides; rigid obstacles measured and refused when thin), and the
scene default (energy conservation in a closed room with a post at the default courant, and
1.0001 x the limit refused: `test_stability.py`)."""

import math

import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np
import pytest

from difflattice.lattice import Edges
from difflattice.lattice.coefficients import build_lattice
from difflattice.lattice.grid import make_grid, stability_limit
from difflattice.lattice.kinds import DEFAULT_COURANT_3D_ISOTROPIC, VOLUME
from difflattice.lattice.medium import Medium
from difflattice.lattice.operators import divergence, face_gradient, stencil
from difflattice.lattice.spectrum import check_spectrum, spectral_radius
from difflattice.observe.analytic3d import lattice_omega_3d, phase_velocity_3d
from difflattice.solver import Stepper, run

jax.config.update("jax_enable_x64", True)

LIMIT = stability_limit("3d", "isotropic")


def _grid(shape, courant=LIMIT):
    return make_grid(
        frequency_hz=40e3,
        cells_per_wavelength=10,
        c_max_m_s=343.0,
        shape=shape,
        courant=courant,
        dtype="float64",
        kind="3d",
        stencil="isotropic",
    )


def test_limit_and_default():
    """sqrt(3)/2 = 2 / sqrt(16/3): the symbol 4 [sum s - (2/3) sum s_i s_j] peaks at 16/3 on
    s = (1, 1, 0); its default courant is 0.86 (scenes default to the wide stencil, test_wide_3d.py)."""
    assert LIMIT == pytest.approx(math.sqrt(3) / 2, abs=1e-15)
    s = np.array([[a, b, c] for a in (0, 1) for b in (0, 1) for c in (0, 1)], float)
    sym = 4 * (s.sum(1) - 2 / 3 * (s[:, 0] * s[:, 1] + s[:, 1] * s[:, 2] + s[:, 0] * s[:, 2]))
    assert sym.max() == pytest.approx(16 / 3)
    assert VOLUME.default_courant_for("isotropic") == DEFAULT_COURANT_3D_ISOTROPIC


def test_discrete_plane_wave_is_exact():
    """A cosine plane wave along a body diagonal with omega from `lattice_omega_3d` stays exact
    (to round-off) away from the window sides; with the 7-point omega it does not."""
    n, steps, c = 40, 12, 0.86
    k = 2 * math.pi / 6 * np.array([1.0, 1.0, 1.0]) / math.sqrt(3)
    x = np.stack(np.meshgrid(*[np.arange(n)] * 3, indexing="ij"), -1).astype(float)
    phase = x @ k
    errs = {}
    for st in ("isotropic", "standard"):
        w = float(lattice_omega_3d(k, c, st))
        stepper = Stepper.build(_grid((n, n, n), courant=c), Medium(343.0, 1.2), edges=Edges.all("rigid"))
        st0 = eqx.tree_at(
            lambda s: (s.p, s.p_prev), stepper.init(), (jnp.asarray(np.cos(phase)), jnp.asarray(np.cos(phase + w)))
        )
        res = run(stepper, steps, state=st0)
        inner = slice(steps + 1, n - steps - 1)
        errs[st] = np.abs(np.asarray(res.final.p) - np.cos(phase - w * steps))[inner, inner, inner].max()
    assert errs["isotropic"] < 1e-11
    assert errs["standard"] > 1e-3


def test_phase_speed_is_isotropic():
    """1.33 % slow at 6 cells/wavelength on axes, face and body diagonals (spread < 0.11 %), where
    the 7-point stencil spreads 0 to 3.4 %."""
    c = DEFAULT_COURANT_3D_ISOTROPIC
    om = 2 * math.pi * c / 6
    errs = [float(phase_velocity_3d(om, c, d, stencil="isotropic")) / c - 1 for d in ((1, 0, 0), (1, 1, 0), (1, 1, 1))]
    assert max(abs(e) for e in errs) < 0.0135 and max(errs) - min(errs) < 0.0011


def _shape_and_posts():
    shape = (14, 13, 12)
    x, y, z = np.meshgrid(*[np.arange(n) for n in shape], indexing="ij")
    post = ((x - 6) ** 2 + (y - 6) ** 2 < 9) | ((x > 9) & (y < 4) & (z < 6))
    return shape, post, (x, y, z)


@pytest.mark.parametrize("side", ["rigid", "soft"])
def test_spectral_radius_within_the_bound(side):
    """c^2 rho(-L) <= 4 at sqrt(3)/2 in air (rigid and soft sides: mirror and odd mirror of the
    whole-space operator) and next to a post and a box (measured: power iteration agrees with
    the dense eigenvalues)."""
    shape, post, _ = _shape_and_posts()
    for rigid in (None, post):
        med = Medium(343.0, 1.2) if rigid is None else Medium(343.0, 1.2, rigid=jnp.asarray(rigid, float))
        lat = build_lattice(_grid(shape), med, Edges.all(side))
        rho = spectral_radius(lat, shape, iters=150)
        assert 3.8 < rho <= 4.0 * (1 + 1e-9), rho  # converged near the bound (checkerboard modes), not above
    small = (6, 5, 4)
    lat = build_lattice(_grid(small), Medium(343.0, 1.2), Edges.all(side))
    n = math.prod(small)
    mat = np.asarray(jax.vmap(lambda e: lat.K * stencil(lat, e.reshape(small)).ravel())(jnp.eye(n)))
    ev = np.linalg.eigvalsh(-(mat + mat.T) / 2)
    assert np.abs(mat - mat.T).max() < 1e-13 and ev.min() > -1e-12 and ev.max() <= 4.0 * (1 + 1e-12)


def test_thin_obstacles_are_refused():
    """Features one cell thin (here random voxels) break the whole-space bound: refused with the fix."""
    shape, _, _ = _shape_and_posts()
    rigid = np.random.default_rng(1).random(shape) < 0.3
    med = Medium(343.0, 1.2, rigid=jnp.asarray(rigid, float))
    with pytest.raises(ValueError, match="measured spectral radius .* lower the grid courant"):
        Stepper.build(_grid(shape), med, edges=Edges.all("rigid"))
    check_spectrum(build_lattice(_grid(shape, courant=0.75), med, Edges.all("rigid")), shape)


@pytest.mark.parametrize("sides", ["rigid", "soft", "mixed"])
@pytest.mark.parametrize("obstacles", ["air", "post", "voxels", "cut_cells"])
def test_row_and_link_forms_equal_the_flux_form(sides, obstacles):
    """The stencil runs as its 19-point row on a padded copy in air, and as a weighted graph
    Laplacian over axis and face-diagonal links next to obstacles; both equal the flux form
    (face values filtered across the faces, then their divergence; the PML's form) to rounding,
    for rigid, soft and mixed window sides, a post, random voxels and fractional cut cells."""
    shape = (9, 8, 7)
    x, y, _ = np.meshgrid(*[np.arange(n) for n in shape], indexing="ij")
    rng = np.random.default_rng(5)
    rigid = {
        "air": None,
        "post": ((x - 4) ** 2 + (y - 4) ** 2 < 4).astype(float),
        "voxels": (rng.random(shape) < 0.3).astype(float),
        "cut_cells": np.clip(2 * rng.random(shape) - 0.8, 0, 1),
    }[obstacles]
    edges = (
        Edges.all(sides)
        if sides != "mixed"
        else Edges(x_lo="rigid", x_hi="soft", y_lo="soft", y_hi="rigid", z_lo="rigid", z_hi="pml", thickness_cells=2)
    )
    med = Medium(343.0, 1.2) if rigid is None else Medium(343.0, 1.2, rigid=jnp.asarray(rigid))
    lat = build_lattice(_grid(shape, courant=0.5), med, edges)
    q = jnp.asarray(np.random.default_rng(3).standard_normal(shape))
    flux = sum(divergence(lat, face_gradient(lat, q, a), a) for a in range(3))
    assert float(jnp.abs(stencil(lat, q) - flux).max()) < 1e-12
