"""Air absorption on the native CPU kernels against the JAX loop, the reference (issue 34): the
leapfrog and the split-field PML kernels carry the two memory fields Q_O, Q_N and the classical
term exactly as `solver.stepper` does (`_relaxed_operand`, `_relaxed_memory`), on 2-D and rz
grids, standard and isotropic stencils, float32 and float64.

Tolerance: both loops evaluate the same update, the kernels in the stepper's order of operations
(XLA may contract a * b + c into FMAs where the kernels' compiler does too, so single roundings
differ). Each step's new pressure then differs by at most ~20 roundings of values bounded by the
run's peak |P| (the split-field update has 16 operations per cell, the absorbing operand 4 more);
the schemes never amplify (energy decays: docs/air.md), so the differences add at most linearly:
|native - jax| <= n_steps * 20 * eps * peak (float64, 97 steps: 4.3e-13 of the peak; float32:
2.3e-4). The memory fields are sums of pressure differences (Q_N ~ P for air's slow N2
relaxation), so their differences are bounded on the same scale, twice over (the pressure's error
fed through g_i dP plus the update's own 3 roundings per step).
"""

import jax
import jax.numpy as jnp
import numpy as np
import pytest

from difflattice.lattice import Edges
from difflattice.lattice.grid import make_grid
from difflattice.lattice.medium import AirConditions
from difflattice.solver import Sensors, Stepper, native, run, simulate
from difflattice.solver.sources import PointSources, ToneBurst

_LIB = native.load()
pytestmark = pytest.mark.skipif(isinstance(_LIB, str), reason=f"native kernels unavailable: {_LIB}")

N = 97  # steps: not a multiple of the chunk (exercises the remainder chunk)
AIR = AirConditions(20.0, 50.0)
EDGES = {
    ("2d", "rigid"): Edges.all("rigid"),
    ("2d", "pml"): Edges(x_lo="rigid", thickness_cells=6),
    ("rz", "rigid"): Edges.axisymmetric("rigid", "rigid", "rigid"),
    ("rz", "pml"): Edges.axisymmetric("rigid", "pml", "pml", thickness_cells=6),
}


def _scene(kind: str, edges: str, stencil: str, dtype: str):
    """A 200 kHz burst (the absorption is strong there: ISO ~9 dB/m at 20 C, 50 % RH) on a 48 x 40
    grid at 6 cells/wavelength, a source off the axis and one on it (rz), probes, phasors and
    field statistics."""
    grid = make_grid(
        frequency_hz=200e3,
        cells_per_wavelength=6,
        c_max_m_s=float(AIR.speed_of_sound_m_s()),
        shape=(48, 40),
        courant=0.6,
        dtype=dtype,
        kind=kind,
        stencil=stencil,
    )
    cells = [(20, 0), (14, 9)] if kind == "rz" else [(20, 20), (14, 9)]
    src = PointSources(cells=cells, signal=ToneBurst(200e3, 2), weights=jnp.ones(2), lags_s=jnp.zeros(2))
    sens = Sensors(probes=[(30, 5), (36, 12)], phasor_cells=[(28, 25), (33, 18)], p_max=True, p_rms=True)
    return grid, src, sens, EDGES[(kind, edges)]


def _check(ref, got, dtype):
    eps = float(jnp.finfo(jnp.dtype(dtype)).eps)
    peak = float(jnp.max(ref.peak_history))
    assert np.isfinite(peak) and peak > 1e-3
    tol = N * 20 * eps * peak
    pairs = [
        ("pressure", ref.final.pressure, got.final.pressure),
        ("probes", ref.probes, got.probes),
        ("peak history", ref.peak_history, got.peak_history),
        ("p_max", ref.p_max, got.p_max),
        ("p_rms", ref.p_rms, got.p_rms),
    ]
    for name, a, b in pairs:
        err = float(jnp.max(jnp.abs(a - b)))
        assert err <= tol, f"{name}: {err:.3g} > {tol:.3g}"
    assert ref.final.relax_q is not None and got.final.relax_q is not None
    for name, a, b in zip(("Q_O", "Q_N"), ref.final.relax_q, got.final.relax_q):
        assert float(jnp.max(jnp.abs(a))) > 1e-3 * peak, name  # the fields are alive
        err = float(jnp.max(jnp.abs(a - b)))
        assert err <= 2 * tol, f"{name}: {err:.3g} > {2 * tol:.3g}"
    err = float(jnp.max(jnp.abs(ref.phasors - got.phasors)))  # sums over N values
    assert err <= N * tol, f"phasors: {err:.3g}"
    return tol


@pytest.mark.parametrize("dtype", ["float32", "float64"])
@pytest.mark.parametrize(
    "kind,edges,stencil",
    [
        ("2d", "rigid", "standard"),
        ("rz", "rigid", "standard"),
        ("2d", "pml", "standard"),
        ("rz", "pml", "standard"),
        ("2d", "rigid", "isotropic"),
        ("rz", "pml", "isotropic"),
    ],
)
def test_absorbing_air_native_equals_jax(kind, edges, stencil, dtype):
    grid, src, sens, edg = _scene(kind, edges, stencil, dtype)
    st = Stepper.build(grid, AIR.medium(), src, sens, edg)
    assert native.why_not(st) is None
    assert st.staggered == (edges == "pml")
    ref = simulate(grid, AIR.medium(), src, sens, n_steps=N, edges=edg, backend="jax", checkpoint=10)
    got = simulate(grid, AIR.medium(), src, sens, n_steps=N, edges=edg, backend="native", checkpoint=10)
    _check(ref, got, dtype)


def test_absorbing_run_continues_from_a_native_state_and_threads_do_not_matter(monkeypatch):
    """Two native runs of 50 + 47 steps (the memory fields carried in the state between them) equal
    one JAX run of 97; threads and temporal blocking do not change the result (bit for bit)."""
    dtype = "float64"
    grid, src, sens, edg = _scene("2d", "rigid", "standard", dtype)
    sens = Sensors(probes=[(30, 5)])
    st = Stepper.build(grid, AIR.medium(), src, sens, edg)
    ref = run(st, N, backend="jax")
    first = run(st, 50, backend="native")
    second = run(st, N - 50, state=first.final, backend="native")
    assert int(second.final.n) == N
    eps = float(jnp.finfo(jnp.dtype(dtype)).eps)
    tol = N * 20 * eps * float(jnp.max(ref.peak_history))
    assert float(jnp.max(jnp.abs(ref.final.p - second.final.p))) <= tol
    for a, b in zip(ref.final.relax_q, second.final.relax_q):
        assert float(jnp.max(jnp.abs(a - b))) <= 2 * tol
    out = []
    for threads, levels in ((1, 1), (3, 5), (2, 64)):
        monkeypatch.setenv("DIFFLATTICE_NATIVE_THREADS", str(threads))
        monkeypatch.setenv("DIFFLATTICE_NATIVE_LEVELS", str(levels))
        r = run(st, N, backend="native")
        out.append((np.asarray(r.final.p), *(np.asarray(q) for q in r.final.relax_q)))
    for o in out[1:]:
        for a, b in zip(out[0], o):
            np.testing.assert_array_equal(a, b)


def test_lossless_air_passes_no_memory_fields_to_the_kernels():
    """Lossless scenes: no memory fields in the state, empty absorption inputs to the kernels (the
    kernels' lossless path: `relax` false, none of the absorbing loops run)."""
    from difflattice.lattice.medium import Medium
    from difflattice.solver.native.kernels import chunk_kernel

    grid, src, sens, edg = _scene("2d", "rigid", "standard", "float32")
    st = Stepper.build(grid, Medium(343.0, 1.2), src, sens, edg)
    assert st.init().relax_q is None
    assert chunk_kernel(st).relax.size == 0
    absorbing = chunk_kernel(Stepper.build(grid, AIR.medium(), src, sens, edg))
    assert absorbing.relax.shape == (7,)


def test_spatially_varying_absorption_is_declined_by_name():
    """The kernels take one value per coefficient; anything else runs the JAX loop under "auto"."""
    import equinox as eqx

    from difflattice.solver.native.kernels import unsupported

    grid, src, sens, edg = _scene("2d", "rigid", "standard", "float64")
    st = Stepper.build(grid, AIR.medium(), src, sens, edg)
    r = st.lattice.relax
    field = jnp.full(grid.shape, r.eps[0])
    varied = eqx.tree_at(lambda s: s.lattice.relax.eps, st, (field, r.eps[1]))
    assert "vary in space" in (unsupported(varied, None, None) or "")
    assert jax.default_backend() == "cpu"
