"""Differentiability on the rz lattice: forward mode = reverse mode and Taylor remainders of slope
2 for a disc transducer's ring weights, ring lags and radius (PML edges: the staggered step with
the cylindrical layer); the adjoint wave equation (`adjoint="lattice"`) = JAX's reverse mode;
checkpointed = plain (a grid split across two devices: `test_sharding.py`, every kind)."""

import jax
import jax.numpy as jnp
import numpy as np
import pytest

from difflattice.lattice import Edges
from difflattice.lattice.grid import make_grid
from difflattice.lattice.medium import Medium
from difflattice.solver import simulate
from difflattice.solver.sensors import Sensors
from difflattice.solver.sources import PointSources, ToneBurst, disc_housing, disc_transducer

jax.config.update("jax_enable_x64", True)

GRID = make_grid(
    frequency_hz=50e3, cells_per_wavelength=10, c_max_m_s=343.0, shape=(44, 30), dtype="float64", kind="rz"
)
DX = GRID.dx_m
EDGES = Edges.axisymmetric("rigid", "pml", "pml", thickness_cells=8)
SENS = Sensors(probes=[(25, 0), (30, 12), (20, 18)], phasor_cells=[(28, 3), (33, 9)])
N_STEPS = 130
N_RINGS = 8
RADIUS = 5.3 * DX  # the rim inside ring 5: Taylor steps stay inside it (ring fractions are smooth there)


def _loss(result):
    return jnp.sum(result.probes**2) + jnp.sum(jnp.abs(result.phasors) ** 2) * 1e-3


def _run(weights, lags, radius, checkpoint=None, edges=EDGES, medium=None, adjoint="autodiff", z_m=0.0, baffle="rigid"):
    src = disc_transducer(
        GRID,
        radius_m=radius,
        z_m=z_m,
        n_rings=N_RINGS,
        weights=weights,
        lags_s=lags,
        signal=ToneBurst(50e3, 2),
        baffle=baffle,
    )
    med = Medium(343.0, 1.2) if medium is None else medium
    return simulate(GRID, med, src, SENS, n_steps=N_STEPS, edges=edges, checkpoint=checkpoint, adjoint=adjoint)


W0 = jnp.linspace(0.7, 1.3, N_RINGS)
L0 = jnp.linspace(0.0, 4.0, N_RINGS)  # microseconds
CASES = {
    "ring weights": (lambda w: _loss(_run(w, jnp.zeros(N_RINGS), RADIUS)), W0),
    "ring lags": (lambda lag_us: _loss(_run(W0, lag_us * 1e-6, RADIUS)), L0),
    "radius": (lambda r_mm: _loss(_run(W0, L0 * 1e-6, r_mm * 1e-3)), jnp.asarray(RADIUS * 1e3)),
}


@pytest.mark.parametrize("name", list(CASES))
def test_forward_reverse_and_taylor(name):
    f, x0 = CASES[name]
    rng = np.random.default_rng(1)
    v = jnp.asarray(rng.normal(size=np.shape(x0)))
    g = jax.grad(f)(x0)
    f0, jv = jax.jvp(f, (x0,), (v,))
    rev = jnp.vdot(g, v)
    # forward and reverse mode are the same derivative computed in a different order: round-off
    assert abs(float(jv - rev)) <= 1e-9 * max(1.0, abs(float(rev))), (float(jv), float(rev))
    # Taylor remainder |f(x + h v) - f(x) - h g.v| = O(h^2): slope 2 on a log-log plot
    hs = np.array([2e-3, 1e-3, 5e-4]) * (float(jnp.linalg.norm(x0)) or 1.0) / float(jnp.linalg.norm(v))
    rem = np.array([abs(float(f(x0 + h * v) - f0 - h * rev)) for h in hs])
    first = np.array([abs(float(f(x0 + h * v) - f0)) for h in hs])
    slopes = np.log2(rem[:-1] / rem[1:])
    assert np.all(slopes > 1.8), (slopes, rem, first)
    assert rem[-1] < 0.05 * first[-1]


def test_checkpointed_gradient_equals_plain():
    f = lambda w, ck: _loss(_run(w, L0 * 1e-6, RADIUS, checkpoint=ck))
    a = jax.grad(lambda w: f(w, None))(W0)
    b = jax.grad(lambda w: f(w, "sqrt"))(W0)
    assert float(jnp.abs(a - b).max()) <= 1e-12 * float(jnp.abs(a).max())


@pytest.mark.slow
def test_lattice_adjoint_equals_autodiff():
    """A disc in a can (a rigid body of revolution with cut cells) in front of a slow dense layer,
    closed, soft and sponge window edges (the leapfrog, which the adjoint path supports):
    gradients for ring weights, lags, radius (source and can) and the layer's contrast (speed,
    which also scales the velocity source, and density) agree with JAX's reverse mode to
    round-off."""
    z, r = np.meshgrid(np.arange(44), np.arange(30), indexing="ij")
    layer = jnp.asarray((z > 30) & (z < 35), jnp.float64)
    edges = Edges.axisymmetric("rigid", "soft", "sponge", thickness_cells=6)

    def loss(adjoint):
        def f(w, lag_us, radius_mm, c_scale):
            # the can follows the disc's radius (cut cells move with it); the layer's speed and
            # density follow c_scale: every coefficient (K, both face conductances) is differentiated
            can = disc_housing(
                GRID, radius_m=radius_mm * 1e-3, z_m=6 * DX, baffle="can", depth_m=3.5 * DX, wall_m=0.7 * DX
            )
            med = Medium(
                343.0 * (1 - 0.02 * c_scale) * (1 - 0.2 * layer * c_scale), 1.2 + 2.0 * layer * c_scale, rigid=can
            )
            res = _run(
                w, lag_us * 1e-6, radius_mm * 1e-3, edges=edges, medium=med, adjoint=adjoint, z_m=6 * DX, baffle="can"
            )
            return _loss(res) + jnp.sum(res.final.pressure * jnp.sin(jnp.asarray(z) / 5.0)) * 0.1

        return f

    args = (W0, L0, jnp.asarray(RADIUS * 1e3), jnp.asarray(1.0))
    ref_val, ref = jax.value_and_grad(loss("autodiff"), argnums=(0, 1, 2, 3))(*args)
    val, got = jax.jit(jax.value_and_grad(loss("lattice"), argnums=(0, 1, 2, 3)))(*args)
    assert abs(float(val - ref_val)) <= 1e-12 * abs(float(ref_val))
    for name, a, b in zip(("weights", "lags", "radius", "speed"), got, ref):
        scale = float(jnp.abs(b).max())
        assert scale > 0, name
        assert float(jnp.abs(a - b).max()) <= 1e-9 * scale, (name, a, b)


def test_point_source_gradient_on_the_axis():
    """A soft point source in the axis cell: forward = reverse (the axis ring's metric factor 0
    on its inner face must not produce NaNs in either mode)."""

    def f(w):
        src = PointSources(cells=[(20, 0)], signal=ToneBurst(50e3, 2), weights=w, lags_s=jnp.zeros(1))
        return _loss(simulate(GRID, Medium(343.0, 1.2), src, SENS, n_steps=N_STEPS, edges=EDGES))

    g = jax.grad(f)(jnp.ones(1))
    _, jv = jax.jvp(f, (jnp.ones(1),), (jnp.ones(1),))
    assert np.isfinite(float(g[0])) and abs(float(jv - g[0])) <= 1e-9 * abs(float(g[0]))
