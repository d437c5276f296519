"""Gradients through the 3-D lattice (f64): JAX's reverse mode of the scan = the adjoint wave
equation (`adjoint="lattice"`, run backwards in 3-D) = forward mode = central finite differences,
for source weights and lags and a cut-cell rigid sphere's radius; JAX's reverse mode runs
checkpointed (chunks of 8 steps recomputed in the backward pass).

Tolerances: the two reverse modes and forward mode compute the same derivative by different
arithmetic: agreement to 1e-9 relative (round-off of ~1e4 operations per cell). Finite
differences with step 1e-6 (relative) err by O(h^2) ~ 1e-10 plus round-off 1e-16 / 1e-6: 1e-6.
"""

import jax
import jax.numpy as jnp
import numpy as np
import pytest

from difflattice.lattice import Edges, Medium
from difflattice.lattice.geometry3d import Sphere, rasterise3d
from difflattice.lattice.grid import make_grid
from difflattice.solver import PointSources, Sensors, ToneBurst, simulate

G = make_grid(
    frequency_hz=40e3, cells_per_wavelength=8, c_max_m_s=343.0, shape=(14, 12, 10), kind="3d", dtype="float64"
)
CELLS = np.array([[3, 6, 5], [3, 7, 5]])
PROBES = np.array([[10, 5, 5], [8, 8, 3]])


def _loss(params, adjoint):
    w, lags, radius = params
    occ = rasterise3d(Sphere(jnp.array([7.5, 6.3, 5.2]) * G.dx_m, radius), G)
    src = PointSources(cells=CELLS, signal=ToneBurst(40e3, 2), weights=w, lags_s=lags)
    r = simulate(
        G,
        Medium(343.0, 1.2, rigid=occ),
        src,
        Sensors(probes=PROBES),
        n_steps=40,
        edges=Edges.all("rigid"),
        adjoint=adjoint,
        checkpoint=8 if adjoint == "autodiff" else None,
    )
    return jnp.sum(r.probes**2)


@pytest.mark.slow  # ~30 s on 2 busy cores, mostly compiling three differentiated programs
def test_reverse_adjoint_forward_and_finite_differences_agree():
    params = (jnp.array([1.0, 0.7]), jnp.array([0.0, 3e-6]), jnp.asarray(2.1 * G.dx_m))
    g_ad = jax.grad(_loss)(params, "autodiff")
    g_lat = jax.grad(_loss)(params, "lattice")
    flat = lambda t: np.concatenate([np.ravel(np.asarray(x)) for x in t])
    a, b = flat(g_ad), flat(g_lat)
    assert np.all(np.abs(a) > 0)
    np.testing.assert_allclose(b, a, rtol=1e-9)
    # forward mode along a random direction
    rng = np.random.default_rng(0)
    v = tuple(jnp.asarray(rng.normal(size=np.shape(x)) * (np.abs(np.asarray(x)) + 1e-6)) for x in params)
    _, jv = jax.jvp(lambda p: _loss(p, "autodiff"), (params,), (v,))
    assert float(jv) == pytest.approx(float(np.dot(a, flat(v))), rel=1e-9)
    # central differences: one weight, one lag, the radius
    for i, j, h in ((0, 1, 1e-6), (1, 1, 1e-12), (2, None, 1e-6 * G.dx_m)):

        def shifted(s, i=i, j=j):
            p = list(params)
            p[i] = p[i] + s if j is None else p[i].at[j].add(s)
            return float(_loss(tuple(p), "autodiff"))

        fd = (shifted(h) - shifted(-h)) / (2 * h)
        an = float(np.ravel(np.asarray(g_ad[i]))[0 if j is None else j])
        assert fd == pytest.approx(an, rel=1e-6), (i, j, fd, an)
