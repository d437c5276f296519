"""Differentiability: forward mode = reverse mode = finite differences (Taylor test, float64),
checkpointed reverse mode = plain reverse mode, and jit/vmap."""

import jax
import jax.numpy as jnp
import numpy as np
import pytest

from difflattice.lattice import Edges
from difflattice.lattice.geometry import Circle, rasterise
from difflattice.lattice.grid import make_grid
from difflattice.lattice.medium import Medium
from difflattice.solver import simulate
from difflattice.solver.sensors import Sensors
from difflattice.solver.sources import ToneBurst, line_transducer

GRID = make_grid(frequency_hz=50e3, cells_per_wavelength=10, c_max_m_s=343.0, shape=(60, 50), dtype="float64")
SENS = Sensors(probes=[(45, 25), (40, 35)], phasor_cells=[(50, 20)])
N_STEPS = 150
EDGES = Edges(thickness_cells=10)


def _src(weights, lags):
    return line_transducer(
        GRID, (15 * GRID.dx_m, 25 * GRID.dx_m), n_cells=6, signal=ToneBurst(50e3, 2), weights=weights, lags_s=lags
    )


def _loss(result):
    return jnp.sum(result.probes**2) + jnp.abs(result.phasors[0]) ** 2 * 1e-3


def loss_weights(w, checkpoint=None):
    return _loss(
        simulate(
            GRID, Medium(343.0, 1.2), _src(w, jnp.zeros(6)), SENS, n_steps=N_STEPS, edges=EDGES, checkpoint=checkpoint
        )
    )


def loss_lags(lags_us):
    return _loss(
        simulate(GRID, Medium(343.0, 1.2), _src(jnp.ones(6), lags_us * 1e-6), SENS, n_steps=N_STEPS, edges=EDGES)
    )


def loss_speed(scale):
    x = jnp.arange(60.0)[:, None] * jnp.ones((1, 50))
    c = 343.0 * jnp.where(x > 30, scale, 1.0)  # a slower block: speed map parameter
    return _loss(simulate(GRID, Medium(c, 1.2), _src(jnp.ones(6), jnp.zeros(6)), SENS, n_steps=N_STEPS, edges=EDGES))


def loss_shape(radius_mm, checkpoint=None):
    occ = rasterise(Circle(jnp.array([30 * GRID.dx_m, 27 * GRID.dx_m]), radius_mm * 1e-3), GRID, "smooth")
    med = Medium(343.0, 1.2, rigid=occ)
    return _loss(
        simulate(GRID, med, _src(jnp.ones(6), jnp.zeros(6)), SENS, n_steps=N_STEPS, edges=EDGES, checkpoint=checkpoint)
    )


CASES = {
    "weights": (loss_weights, jnp.linspace(0.5, 1.5, 6)),
    "lags": (loss_lags, jnp.linspace(0.0, 3.0, 6)),
    "speed": (loss_speed, jnp.asarray(0.8)),
    "shape": (loss_shape, jnp.asarray(1.7)),
}


@pytest.mark.parametrize("name", list(CASES))
def test_forward_reverse_and_taylor(name):
    f, x0 = CASES[name]
    rng = np.random.default_rng(0)
    v = jnp.asarray(rng.normal(size=np.shape(x0)))
    g = jax.grad(f)(x0)
    f0, jv = jax.jvp(f, (x0,), (v,))
    rev = jnp.vdot(g, v)
    assert abs(float(jv - rev)) <= 1e-9 * max(1.0, abs(float(rev)))
    # Taylor remainder |f(x + h v) - f(x) - h g.v| = O(h^2): slope 2 on a log-log plot
    hs = np.array([2e-3, 1e-3, 5e-4]) * (float(jnp.linalg.norm(x0)) or 1.0) / float(jnp.linalg.norm(v))
    rem = np.array([abs(float(f(x0 + h * v) - f0 - h * rev)) for h in hs])
    first = np.array([abs(float(f(x0 + h * v) - f0)) for h in hs])
    slopes = np.log2(rem[:-1] / rem[1:])
    assert np.all(slopes > 1.8), (slopes, rem, first)
    assert rem[-1] < 0.05 * first[-1]  # the gradient term dominates


def test_checkpointed_gradient_equals_plain():
    w = jnp.linspace(0.5, 1.5, 6)
    g_plain = jax.grad(loss_weights)(w)
    g_ck = jax.grad(lambda w: loss_weights(w, checkpoint="sqrt"))(w)
    np.testing.assert_allclose(np.asarray(g_ck), np.asarray(g_plain), rtol=1e-10)
    gs = jax.grad(loss_shape)(jnp.asarray(1.7))
    gs_ck = jax.grad(lambda r: loss_shape(r, checkpoint=7))(jnp.asarray(1.7))
    assert float(gs_ck) == pytest.approx(float(gs), rel=1e-10)


def test_jit_and_vmap_over_weights():
    ws = jnp.stack([jnp.ones(6), 2 * jnp.ones(6), jnp.linspace(0, 1, 6)])
    batched = jax.jit(jax.vmap(loss_weights))(ws)
    single = jnp.stack([loss_weights(w) for w in ws])
    np.testing.assert_allclose(np.asarray(batched), np.asarray(single), rtol=1e-12)
    # linearity of the field in the weights: loss of 2w = 4 x loss of w
    assert float(batched[1]) == pytest.approx(4 * float(batched[0]), rel=1e-12)
