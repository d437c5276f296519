"""The 3-D lattice (Grid.kind = "3d", the 7-point leapfrog) against independent references.

1. Dispersion: an exact discrete plane wave cos(k.x - omega t) with |k| solved from the 3-D
   dispersion relation (`analytic3d.lattice_wavenumber_3d`) at a given omega (20 cells per
   wavelength), along the axis and the body diagonal, stays exact to round-off (< 1e-10, f64) in
   the part of the grid the edges cannot reach yet: the lattice's phase velocity is the relation's
   to ~1e-12. The continuum |k| = omega / c must not (so the test can fail).
2. Energy conservation in a closed box at the limit 1/sqrt(3), and 1.0001 / sqrt(3) refused:
   `test_stability.py` (every kind).
3. Stability limit: a traced speed above it refused at run time; non-finite fields detected.
4. Point source: the lattice's own Green's function (stationary phase of the dispersion surface,
   `analytic3d.point_source_phasor`: exactly 1/(4 pi r) in amplitude along the axis, 1.7 % more on
   the diagonal at 20 cells per wavelength) against the simulated phasor from 10 to 100 cells
   along the axis and the diagonal: within 1 %, and r |P| flat within 1 % along each ray.
"""

import math

import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np
import pytest

from difflattice.lattice import Edges, Medium
from difflattice.lattice.grid import MAX_COURANT_3D, make_grid
from difflattice.observe.analytic3d import lattice_wavenumber_3d, mirror_points, point_source_phasor
from difflattice.solver import PointSources, Sensors, Stepper, ToneBurst, check_result, run, simulate


def _grid(shape, courant=None, ppw=20.0, dtype="float64"):
    return make_grid(
        frequency_hz=40e3,
        cells_per_wavelength=ppw,
        c_max_m_s=343.0,
        shape=shape,
        kind="3d",
        courant=courant,
        dtype=dtype,
    )


N_STEPS = 20


@pytest.mark.parametrize("direction", [(1, 0, 0), (1, 1, 1)])
def test_plane_wave_follows_the_3d_dispersion_relation(direction):
    n = 64
    g = _grid((n, n, n), courant=MAX_COURANT_3D)
    c, omega = g.courant, g.omega
    u = np.asarray(direction, float) / np.linalg.norm(direction)
    x = np.stack(np.meshgrid(*(np.arange(n),) * 3, indexing="ij"), -1) @ u
    inner = (slice(N_STEPS + 1, n - N_STEPS - 1),) * 3
    errs = {}
    for name, k in (("lattice", float(lattice_wavenumber_3d(omega, c, u))), ("continuum", omega / c)):
        st = Stepper.build(g, Medium(343.0, 1.2), edges=Edges.all("rigid"))
        s0 = eqx.tree_at(
            lambda s: (s.p, s.p_prev), st.init(), (jnp.asarray(np.cos(k * x)), jnp.asarray(np.cos(k * x + omega)))
        )
        res = run(st, N_STEPS, state=s0)
        exact = np.cos(k * x - omega * N_STEPS)
        errs[name] = np.abs(np.asarray(res.final.p) - exact)[inner].max()
    assert errs["lattice"] < 1e-10, errs
    if direction == (1, 0, 0):
        # phase error N (omega_c - omega_lattice) ~ 20 * 0.0027 * 0.18 ~ 1e-2 on the axis; the
        # diagonal at the Courant limit is exact (no continuum error to detect there)
        assert errs["continuum"] > 1e-3, errs


def test_traced_speed_refused_and_instability_detected():
    g = _grid((10, 10, 10), courant=0.57, dtype="float32")

    @jax.jit
    def f(c):
        med = Medium(c * jnp.ones((10, 10, 10), jnp.float32), 1.2)
        return simulate(g, med, (), Sensors(), n_steps=5, edges=Edges.all("rigid")).peak_history

    f(jnp.float32(343.0)).block_until_ready()
    with pytest.raises((eqx.EquinoxRuntimeError, ValueError), match="1/sqrt\\(3\\)"):
        f(jnp.float32(400.0)).block_until_ready()
    src = PointSources(
        cells=[(5, 5, 5)], signal=ToneBurst(40e3, 2), weights=jnp.ones(1, jnp.float32), lags_s=jnp.zeros(1, jnp.float32)
    )
    st = Stepper.build(g, Medium(343.0, 1.2), src, edges=Edges.all("rigid"))
    bad = eqx.tree_at(lambda s: s.lattice.K, st, jnp.asarray(0.4, jnp.float32))  # c = 0.63 > 0.577
    res = run(bad, 2000)
    with pytest.raises(eqx.EquinoxRuntimeError, match="non-finite pressure"):
        check_result(res, bad).peak_history.block_until_ready()


def test_point_source_falls_as_one_over_r():
    """One octant: rigid faces at x, y, z = -1/2 mirror the source cell (0, 0, 0) into a cube of 8
    cells centred at (-1/2, -1/2, -1/2); the reference sums the 8 lattice Green's functions. The
    far walls are rigid and far enough that each probe's DFT window (ending before the first wall
    echo reaches it) holds the whole direct 2-cycle burst."""
    shape = (124, 94, 94)
    g = _grid(shape)
    c, w = g.courant, g.omega
    sig = ToneBurst(40e3, 2.0)
    src = PointSources(cells=[(0, 0, 0)], signal=sig, weights=jnp.ones(1), lags_s=jnp.zeros(1))
    r = np.arange(10, 101, 5)
    a = np.round(r / math.sqrt(3) - 0.5).astype(int)
    rays = {"axis": np.stack([r, 0 * r, 0 * r], 1), "diagonal": np.stack([a, a, a], 1)}
    cells = np.concatenate(list(rays.values()))
    centre = np.full(3, -0.5)
    direct = np.linalg.norm(cells - centre, axis=1)
    echo = np.min(
        [
            np.linalg.norm(cells - mirror_points(centre, np.eye(3)[i] * (shape[i] - 0.5), np.eye(3)[i]), axis=1)
            for i in range(3)
        ],
        axis=0,
    )
    end = np.floor(echo / c).astype(int)
    assert np.all(end > direct / c + 2 * g.steps_per_period + 8)  # the burst ends inside each window
    n_steps = int(end.max())
    res = simulate(g, Medium(343.0, 1.2), src, Sensors(probes=cells), n_steps=n_steps, edges=Edges.all("rigid"))
    n = np.arange(1, n_steps + 1)
    ph = np.sum(np.where(n[:, None] <= end, np.asarray(res.probes), 0) * np.exp(1j * w * n)[:, None], axis=0)
    v_hat = np.sum(np.asarray(sig(n * g.dt_s)) * np.exp(1j * w * n))
    images = np.array([[sx, sy, sz] for sx in (0, -1) for sy in (0, -1) for sz in (0, -1)], float)
    ref = np.array([sum(point_source_phasor(x - im, w, c, v_hat) for im in images) for x in cells.astype(float)])
    err = np.abs(np.abs(ph) / np.abs(ref) - 1)
    assert err.max() < 0.01, err.max()
    i = 0
    for name, cl in rays.items():
        rp = direct[i : i + len(cl)] * np.abs(ph[i : i + len(cl)])
        assert rp.max() / rp.min() < 1.01, (name, rp.max() / rp.min())
        i += len(cl)
