"""Sources, sensors, absorption, and the 'only what the scene uses' rule."""

import math

import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np
import pytest

from difflattice.lattice import Edges
from difflattice.lattice.grid import make_grid
from difflattice.lattice.medium import Medium
from difflattice.solver import Stepper, simulate
from difflattice.solver.sensors import Sensors
from difflattice.solver.sources import PointSources, ToneBurst, line_transducer

G = make_grid(frequency_hz=50e3, cells_per_wavelength=12, c_max_m_s=343.0, shape=(80, 70), dtype="float64")
E = Edges(thickness_cells=12)


def _src(y, w=1.0, injection="soft"):
    return line_transducer(
        G, (25 * G.dx_m, y * G.dx_m), n_cells=8, signal=ToneBurst(50e3, 3), injection=injection, weights=jnp.full(8, w)
    )


def test_soft_sources_superpose():
    sens = Sensors(probes=[(55, 30), (60, 45)])
    a = simulate(G, Medium(343.0, 1.2), _src(25), sens, n_steps=200, edges=E).probes
    b = simulate(G, Medium(343.0, 1.2), _src(45, 2.0), sens, n_steps=200, edges=E).probes
    ab = simulate(G, Medium(343.0, 1.2), (_src(25), _src(45, 2.0)), sens, n_steps=200, edges=E).probes
    np.testing.assert_allclose(np.asarray(ab), np.asarray(a + b), atol=1e-12 * float(jnp.abs(ab).max()))


def test_hard_source_sets_the_pressure():
    src = _src(35, 1.0, "hard")
    cells = src.cells_array
    r = simulate(G, Medium(343.0, 1.2), src, Sensors(probes=cells), n_steps=80, edges=E)
    t = (np.arange(1, 81)) * G.dt_s
    expected = np.asarray(src.signal(jnp.asarray(t)))
    np.testing.assert_allclose(np.asarray(r.probes[:, 0]), expected, atol=1e-12)


def test_arrival_time_matches_lattice_group_speed():
    """First arrival of a point source's burst at a probe 30 cells away on the axis: within the
    rise time of the threshold crossing (a few steps) of distance / group speed."""
    src = PointSources(cells=[(20, 35)], signal=ToneBurst(50e3, 2, "rect"), weights=jnp.ones(1), lags_s=jnp.zeros(1))
    r = simulate(G, Medium(343.0, 1.2), src, Sensors(arrival_threshold_pa=1e-3, p_max=True), n_steps=150, edges=E)
    arr = np.asarray(r.arrival)
    steps = arr[50, 35]
    # the wavefront (leading edge) moves at most 1 cell/step and at least at the lattice speed c
    assert 30 <= steps <= 30 / G.courant + 6
    assert arr[50, 35] > arr[35, 35] > 0


def test_absorption_gives_requested_db_per_m():
    """A plane wave's amplitude at the drive frequency falls by the requested dB/m (viscous law:
    exact for the drive frequency up to O((k dx)^2) of the lattice, 2 % tolerance)."""
    alpha = 40.0  # dB/m, strong so the effect is measurable over a short path
    grid = make_grid(frequency_hz=50e3, cells_per_wavelength=20, c_max_m_s=343.0, shape=(700, 1), dtype="float64")
    src = PointSources(cells=[(100, 0)], signal=ToneBurst(50e3, 10), weights=jnp.ones(1), lags_s=jnp.zeros(1))
    e = Edges(x_lo="pml", x_hi="pml", y_lo="rigid", y_hi="rigid")
    p1, p2 = 200, 500
    sens = Sensors(phasor_cells=[(p1, 0), (p2, 0)])
    r = simulate(grid, Medium(343.0, 1.2, absorption_db_per_m=alpha), src, sens, n_steps=1600, edges=e)
    ph = np.asarray(r.phasors)
    measured = 20 * math.log10(abs(ph[0]) / abs(ph[1])) / ((p2 - p1) * grid.dx_m)
    assert measured == pytest.approx(alpha, rel=0.02)
    r0 = simulate(grid, Medium(343.0, 1.2), src, sens, n_steps=1600, edges=e)
    ph0 = np.asarray(r0.phasors)
    assert abs(20 * math.log10(abs(ph0[0]) / abs(ph0[1]))) < 0.01  # no loss without absorption


def _n_eqns(stepper):
    jaxpr = jax.make_jaxpr(lambda s: stepper.step(s))(stepper.init())
    return len(jaxpr.jaxpr.eqns)


def _grid_sized_inputs(stepper):
    """Arrays of (about) the grid's size that one step reads besides its own state: coefficient
    maps. Each costs a full pass over memory per step."""
    n = stepper.grid.shape[0] * stepper.grid.shape[1]
    leaves = jax.tree_util.tree_leaves(eqx.filter(stepper, eqx.is_array))
    return sum(1 for a in leaves if a.size >= 0.9 * n)


def test_step_contains_only_what_the_scene_uses():
    src = _src(35)
    plain = Stepper.build(G, Medium(343.0, 1.2), src, Sensors(), Edges.all("rigid"))
    lat = plain.lattice
    assert lat.q_scale is None and lat.bx is None and lat.keep is None and lat.sponge is None and lat.pml is None
    assert jnp.ndim(lat.K) == 0 and lat.eta == 0.0
    x = jnp.arange(80.0)[:, None] * jnp.ones((1, 70))
    full = Stepper.build(
        G,
        Medium(
            jnp.where(x > 50, 300.0, 343.0),
            jnp.where(x > 50, 2.0, 1.2),
            rigid=(x > 70).astype(jnp.float64),
            absorption_db_per_m=1.0,
        ),
        src,
        Sensors(p_max=True, p_rms=True, phasor_cells=[(60, 30)]),
        E,
    )
    # the plain scene's step reads no coefficient map at all and has far fewer operations
    assert _grid_sized_inputs(plain) == 0
    assert _grid_sized_inputs(full) >= 4  # K, two face conductances, c (and the phasor state)
    assert _n_eqns(plain) < 0.6 * _n_eqns(full)
