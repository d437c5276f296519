"""The native 3-D kernel (`difflattice.solver.native.volume`, FFI target `difflattice_volume`)
against the JAX 3-D loop, the reference: the same fields, probes, phasors and statistics to
rounding for homogeneous air and for obstacles with cut cells, a medium change, soft cells and
every window side kind it runs (PML layers included), with the standard and (on uniform faces)
the isotropic stencil, in float32 and float64; threads and temporal blocking never change
a result (bit for bit); what it does not run is refused by name and falls back to the JAX loop.

Tolerance: both loops evaluate the same update (~10 operations per cell: three axis terms, their
sum, K, the leapfrog, the sponge or keep factor) with the operations in a different order or
contracted differently into FMAs, so each step's new field differs by at most ~10 roundings of
values bounded by the run's peak |p|; the leapfrog is neutrally stable, so the differences add at
most linearly: |native - jax| <= n_steps * 10 * eps * peak.
"""

import dataclasses

import jax
import jax.numpy as jnp
import numpy as np
import pytest

from difflattice.lattice import Edges, Medium
from difflattice.lattice.geometry3d import Sphere, rasterise3d
from difflattice.lattice.grid import make_grid
from difflattice.solver import Sensors, Stepper, native, run
from difflattice.solver.native.volume import VolumeChunk, unsupported_3d
from difflattice.solver.sources import PointSources, ToneBurst

_LIB = native.load()
pytestmark = pytest.mark.skipif(isinstance(_LIB, str), reason=f"native kernels unavailable: {_LIB}")

N = 41  # steps: odd (the kernel's buffers swap), one chunk
SHAPE = (22, 18, 16)
SENS = Sensors(
    probes=[(15, 9, 8), (4, 3, 12)],
    phasor_cells=[(12, 10, 7), (6, 6, 6)],
    p_max=True,
    p_rms=True,
    arrival_threshold_pa=1e-3,
)


def _grid(dtype="float32", **kw):
    return make_grid(frequency_hz=40e3, cells_per_wavelength=10, c_max_m_s=343.0, shape=SHAPE, dtype=dtype, **kw)


def _sources(g):
    soft = PointSources(np.array([[5, 9, 8], [5, 10, 8]]), ToneBurst(40e3, 2), jnp.ones(2), jnp.array([0.0, 3e-6]))
    hard = PointSources(np.array([[5, 9, 9]]), ToneBurst(40e3, 2), jnp.ones(1) * 0.5, jnp.zeros(1), injection="hard")
    return (soft, hard)


MIXED = Edges(x_lo="rigid", x_hi="soft", y_lo="soft", y_hi="rigid", z_lo="rigid", z_hi="soft")


def _scene(kind, dtype):
    """(grid, medium, edges) of a scene kind."""
    if kind.startswith("isotropic"):  # the 19-point stencil on uniform faces (air)
        g = _grid(dtype, kind="3d", stencil="isotropic")
        edges = Edges.all("sponge", thickness_cells=4) if kind == "isotropic_sponge" else MIXED
        return g, Medium(343.0, 1.2), edges
    g = _grid(dtype, kind="3d")
    h = g.dx_m
    if kind == "pml":  # the split-field layers on six boxes
        return g, Medium(343.0, 1.2), Edges.all("pml", thickness_cells=4)
    if kind == "homogeneous":
        return g, Medium(343.0, 1.2), Edges.all("rigid")
    if kind == "homogeneous_mixed":
        return g, Medium(343.0, 1.2), MIXED
    if kind == "sponge":
        return g, Medium(343.0, 1.2), Edges.all("sponge", thickness_cells=4)
    x = jnp.arange(SHAPE[0])[:, None, None] * jnp.ones(SHAPE)
    rigid = rasterise3d(Sphere(jnp.array([14.3 * h, 8.6 * h, 8.2 * h]), jnp.asarray(3.4 * h)), g, "smooth")
    if kind == "obstacle_medium":  # cut cells (a smooth sphere) and a denser, slower slab of gas
        med = Medium(jnp.where(x > 18, 300.0, 343.0), jnp.where(x > 18, 1.8, 1.2), rigid=rigid)
        return g, med, MIXED
    if kind == "pml_obstacle":  # cut cells, a medium change and PML on five sides
        med = Medium(jnp.where(x > 18, 300.0, 343.0), jnp.where(x > 18, 1.8, 1.2), rigid=rigid)
        return g, med, Edges(x_lo="rigid", thickness_cells=3)
    if kind == "soft_obstacle":
        soft = ((x > 16) & (x < 18)).astype(g.jnp_dtype)
        return g, Medium(343.0, 1.2, rigid=rigid, soft=soft), Edges.all("soft")
    raise ValueError(kind)


KINDS = (
    "homogeneous",
    "homogeneous_mixed",
    "sponge",
    "obstacle_medium",
    "soft_obstacle",
    "isotropic_mixed",
    "isotropic_sponge",
    "pml",
    "pml_obstacle",
)


def _build(kind, dtype, sens=SENS):
    g, med, edges = _scene(kind, dtype)
    return Stepper.build(g, med, _sources(g), sens, edges)


def _close(a, b, dtype, peak, n=N):
    tol = n * 10 * float(jnp.finfo(dtype).eps) * peak
    a, b = np.asarray(a, np.float64), np.asarray(b, np.float64)
    assert a.shape == b.shape
    err = float(np.max(np.abs(a - b))) if a.size else 0.0
    assert err <= tol, f"max |native - jax| = {err:.3g} > {tol:.3g}"


@pytest.mark.parametrize("kind", KINDS)
def test_native_3d_equals_the_jax_loop_float32(kind):
    st = _build(kind, "float32")
    assert native.why_not(st) is None
    ref = run(st, N, backend="jax")
    got = run(st, N, backend="native")
    peak = float(jnp.max(ref.final.p_max))
    assert peak > 0.1  # the burst reached the field
    for name in ("p", "p_prev", "p_max"):
        _close(getattr(got.final, name), getattr(ref.final, name), jnp.float32, peak)
    _close(got.final.p_sq, ref.final.p_sq, jnp.float32, 2 * peak * float(jnp.max(ref.final.p_sq)) ** 0.5)
    _close(got.final.phasor_re, ref.final.phasor_re, jnp.float32, peak * N)
    _close(got.final.phasor_im, ref.final.phasor_im, jnp.float32, peak * N)
    _close(got.probes, ref.probes, jnp.float32, peak)
    if st.staggered:  # the layers' parts (pressure-like) and face fluxes (bounded by the peak's differences)
        for lg, lr in zip(got.final.layers, ref.final.layers):
            for a, b in zip(lg.parts + lg.fluxes, lr.parts + lr.fluxes):
                _close(a, b, jnp.float32, 2 * peak)
    _close(got.peak_history, ref.peak_history, jnp.float32, peak)
    # first arrivals: the same step wherever |p| is not within rounding of the threshold at it
    a_ref, a_got = np.asarray(ref.final.arrival), np.asarray(got.final.arrival)
    assert np.mean(a_ref == a_got) > 0.999
    assert int(got.final.n) == N


@pytest.mark.parametrize("kind", ("homogeneous_mixed", "obstacle_medium", "isotropic_mixed", "pml_obstacle"))
def test_native_3d_equals_the_jax_loop_float64(kind):
    # (tests/conftest.py enables float64 for the whole session)
    st = _build(kind, "float64")
    assert native.why_not(st) is None
    ref = run(st, N, backend="jax")
    got = run(st, N, backend="native")
    peak = float(jnp.max(ref.final.p_max))
    for name in ("p", "p_prev", "p_max"):
        _close(getattr(got.final, name), getattr(ref.final, name), jnp.float64, peak)
    _close(got.probes, ref.probes, jnp.float64, peak)
    assert np.array_equal(np.asarray(got.final.arrival), np.asarray(ref.final.arrival))


def test_snapshots_and_chunks_of_a_native_3d_run():
    """Several chunks and a remainder, snapshots as the sensors' planes: as the JAX loop's."""
    sens = Sensors(probes=[(8, 9, 8)], snapshot_every=16)
    st = _build("homogeneous_mixed", "float32", sens)
    ref = run(st, N, backend="jax")
    got = run(st, N, backend="native")
    assert ref.snapshot_steps == got.snapshot_steps == (16, 32, N)
    peak = max(float(jnp.max(jnp.abs(x))) for x in jax.tree_util.tree_leaves(ref.snapshots))
    for a, b in zip(jax.tree_util.tree_leaves(got.snapshots), jax.tree_util.tree_leaves(ref.snapshots)):
        _close(a, b, jnp.float32, peak)
    _close(got.probes, ref.probes, jnp.float32, peak)


@pytest.mark.parametrize("kind", ("homogeneous_mixed", "obstacle_medium", "sponge", "isotropic_mixed", "pml_obstacle"))
def test_threads_levels_and_bands_never_change_a_3d_result(kind):
    st = _build(kind, "float32")
    s0 = st.init()
    outs = []
    # (threads, steps per sweep, rows of a plane's bands: 0 = whole planes); 3 threads x 1 level: 41
    # steps in 14 blocks of 2-3, so a block leaves a thread idle and the next block's first thread
    # waits for the one before the idle one (the whole-plane pipeline has no barrier between blocks)
    for threads, levels, band in (
        (1, 1, 0),
        (2, 1, 0),
        (2, 3, 0),
        (3, 2, 0),
        (3, 1, 0),
        (4, 3, 0),
        (1, 5, 0),
        (1, 3, 4),
        (2, 2, 5),
        (3, 4, 7),
    ):
        fin, rec = VolumeChunk(st, threads, levels, band).advance(s0, N)
        outs.append((np.asarray(fin.p), np.asarray(fin.p_prev), np.asarray(rec), np.asarray(fin.p_sq)))
    for o in outs[1:]:
        for a, b in zip(o, outs[0]):
            assert np.array_equal(a, b)


def test_what_the_3d_kernel_does_not_run_is_refused_by_name():
    g = _grid(kind="3d")
    med = Medium(343.0, 1.2)
    g_iso = _grid(kind="3d", stencil="isotropic")
    pml = Stepper.build(g_iso, med, edges=Edges.all("pml", thickness_cells=4))
    assert "PML edges with the 'isotropic' stencil on a 3-D grid" in native.why_not(pml)
    with pytest.raises(ValueError, match="PML edges with the 'isotropic' stencil"):
        run(pml, 3, backend="native")
    auto = run(pml, 3)  # backend="auto": the JAX loop runs it
    assert isinstance(auto.final, type(pml.init()))
    ball = rasterise3d(Sphere(jnp.array([11.0, 9.0, 8.0]) * g.dx_m, jnp.asarray(3.0 * g.dx_m)), g_iso)
    iso = Stepper.build(g_iso, Medium(343.0, 1.2, rigid=ball), edges=Edges.all("rigid"))
    assert "'isotropic' stencil with face conductances" in native.why_not(iso)
    rigid = Stepper.build(g, med, edges=Edges.all("rigid"))
    other = dataclasses.replace(rigid, lattice=dataclasses.replace(rigid.lattice, stencil="wide3d"))
    assert "'wide3d' stencil on a 3-D grid" in unsupported_3d(other, None)
    lossy = Stepper.build(g, Medium(343.0, 1.2, absorption_db_per_m=0.5), edges=Edges.all("rigid"))
    assert "viscous absorption" in native.why_not(lossy)
