"""Shape gradients of `geometry.rasterise` on an rz grid are the same under `jax.jit` as eagerly,
and both match central finite differences (float64), for a cone of revolution (its mouth diameter)
and a paraboloidal dish (its focal length).

Before the fix, `jnp.clip` / `jnp.hypot` / `jnp.min` in the signed distances were differentiated
by equality with their results; XLA on a CPU with FMA recomputes the operand in another fusion
with a different rounding, the equality fails and cell gradients are dropped: under `jit` the
cone's mouth gradient came out -61.0 against 15.25 eagerly, the dish's focal gradient 0.73x the
eager one (see `lattice/geometry.py`).

Tolerances. `jit` vs eager: the same expression in the same precision, so agreement to 1e-9
relative (round-off of a sum over ~100 cells is ~1e-14). Finite differences, step h = 1e-4 cells:
the occupancy is a C1 smoothstep of a piecewise-smooth distance, so the central difference's
truncation error is ~h^2 f'''/6 ~ (1e-4)^2 of the gradient's scale and its round-off
eps |f| / h ~ 1e-16 * 10 / (1e-4 dx) ~ 1e-8 absolute; a cell whose ramp ends within h of its
centre (the smoothstep is C1, not C2) adds an O(h) error. rtol 1e-6 covers these, and the Richardson
estimate |D(2h) - D(h)| / 3 is asserted to lie below it, so the difference itself is known to be
that accurate rather than the tolerance being widened to fit."""

import equinox as eqx
import jax.numpy as jnp
import numpy as np
import pytest

from difflattice.lattice.geometry import HornWalls, ParabolicMirror, rasterise
from difflattice.lattice.grid import make_grid

GRID = make_grid(
    frequency_hz=50e3, cells_per_wavelength=6.0, c_max_m_s=343.2, shape=(60, 40), dtype="float64", kind="rz"
)
DX = GRID.dx_m
ANCHOR = (20.5 * DX, 0.0)  # on the axis, as the rz design problems put the disc centre
WEIGHTS = jnp.asarray(np.random.default_rng(12).normal(size=GRID.shape))

CONE = HornWalls(
    throat_centre_m=jnp.asarray(ANCHOR),
    throat_m=jnp.asarray(0.012),
    mouth_m=jnp.asarray(0.022),
    length_m=jnp.asarray(0.018),
    wall_m=jnp.asarray(0.0018),
    flare=jnp.asarray(0.0),  # flare 0: a cone
)
DISH = ParabolicMirror(
    focus_m=jnp.asarray((40.5 * DX, 0.0)),
    focal_m=jnp.asarray(0.012),
    aperture_m=jnp.asarray(0.040),
    wall_m=jnp.asarray(0.0015),
)


def _objective(ramp_cells):
    return lambda shape: jnp.sum(WEIGHTS * rasterise(shape, GRID, "smooth", ramp_cells=ramp_cells))


@pytest.mark.parametrize(
    "shape, where, ramp_cells",
    [
        (CONE, lambda s: s.mouth_m, 1.0),
        (CONE, lambda s: s.length_m, 2.0),
        (DISH, lambda s: s.focal_m, 1.0),
    ],
    ids=["cone-mouth", "cone-length-ramp2", "dish-focal"],
)
def test_rz_shape_gradient_under_jit_matches_eager_and_central_differences(shape, where, ramp_cells):
    f = _objective(ramp_cells)
    g_eager = float(where(eqx.filter_grad(f)(shape)))
    g_jit = float(where(eqx.filter_jit(eqx.filter_grad(f))(shape)))
    f_jit = eqx.filter_jit(f)
    h = 1e-4 * DX

    def at(d):
        return float(f_jit(eqx.tree_at(where, shape, where(shape) + d)))

    d1 = (at(h) - at(-h)) / (2 * h)
    d2 = (at(2 * h) - at(-2 * h)) / (4 * h)
    assert abs(d2 - d1) / 3 < 1e-6 * abs(d1), (d1, d2)  # the difference itself is accurate to rtol 1e-6
    assert abs(g_jit - g_eager) <= 1e-9 * abs(g_eager), (g_jit, g_eager)
    assert abs(g_jit - d1) <= 1e-6 * abs(d1), (g_jit, d1)
    assert abs(d1) > 1.0  # the parameter moves the occupancy (weights O(1), tens of cells on the wall)
