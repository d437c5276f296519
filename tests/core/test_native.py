"""The native CPU kernels (`difflattice.solver.native`) against the JAX loop, the reference: the
same fields, probes, phasors and statistics to rounding in every scene kind they run; scenes they
do not run fall back to the JAX loop under backend="auto" and are refused under "native";
derivatives through a native run are the JAX loop's; threads and temporal blocking never change
a result.

Tolerance: both loops evaluate the same update with the operations in a different order, so each
step's new field differs by at most ~16 roundings (the split-field PML update has 16 operations
per cell) of values bounded by the run's peak |p|; the schemes are neutrally stable, so the
differences add at most linearly: |native - jax| <= n_steps * 16 * eps * peak.
"""

import os

import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np
import pytest

from difflattice.lattice import Edges
from difflattice.lattice.grid import make_grid
from difflattice.lattice.medium import Medium
from difflattice.solver import Sensors, Stepper, native, run, simulate
from difflattice.solver.native import build
from difflattice.solver.sources import PointSources, ToneBurst, line_transducer

_LIB = native.load()
pytestmark = pytest.mark.skipif(isinstance(_LIB, str), reason=f"native kernels unavailable: {_LIB}")

N = 97  # steps: not a multiple of the chunk (exercises the remainder chunk)
SHAPE = (48, 40)
X = jnp.arange(48.0)[:, None] * jnp.ones((1, 40))
SENS = Sensors(
    probes=[(30, 20), (36, 12)],
    phasor_cells=[(28, 25), (33, 18), (40, 30), (33, 18)],
    p_max=True,
    p_rms=True,
    arrival_threshold_pa=1e-3,
)


def _grid(dtype, courant=None, kind=None):
    kw = {} if courant is None else {"courant": courant}
    if kind is not None:
        kw["kind"] = kind
    return make_grid(frequency_hz=50e3, cells_per_wavelength=10, c_max_m_s=343.0, shape=SHAPE, dtype=dtype, **kw)


def _scene(kind, dtype):
    """(grid, medium, sources, sensors, edges) of a scene kind."""
    g = _grid(dtype, courant=0.6 if kind.startswith("absorbing") else None)
    rho = jnp.where(X > 30, 2.0, 1.2)
    rigid = (X > 42).astype(jnp.float64)
    soft = ((X < 4) & (X > 1)).astype(jnp.float64)
    src = line_transducer(g, (14 * g.dx_m, 20 * g.dx_m), n_cells=5, signal=ToneBurst(50e3, 2))
    hard = line_transducer(g, (14 * g.dx_m, 20 * g.dx_m), n_cells=5, signal=ToneBurst(50e3, 2), injection="hard")
    sens = SENS
    if kind == "homogeneous":
        return g, Medium(343.0, 1.2), src, sens, Edges.all("rigid")
    if kind == "conservative":  # density map, rigid and soft obstacles, rigid and soft window sides
        return (
            g,
            Medium(343.0, rho, rigid=rigid, soft=soft),
            src,
            sens,
            Edges(x_lo="soft", x_hi="rigid", y_lo="rigid", y_hi="soft"),
        )
    if kind == "conservative+pml":
        return g, Medium(343.0, rho, rigid=rigid, soft=soft), (src, hard), sens, Edges(thickness_cells=6)
    if kind == "homogeneous+pml":
        return g, Medium(343.0, 1.2), hard, sens, Edges(x_lo="rigid", thickness_cells=6)
    if kind == "speed_zero+sponge":
        return (
            g,
            Medium(343.0, 1.2, rigid=rigid, boundary_model="speed_zero"),
            hard,
            sens,
            Edges.all("sponge", thickness_cells=6),
        )
    if kind == "absorbing":
        return g, Medium(343.0, rho, absorption_db_per_m=3.0), src, sens, Edges.all("rigid")
    if kind == "absorbing+pml":
        return g, Medium(343.0, rho, absorption_db_per_m=3.0), src, sens, Edges(thickness_cells=6)
    if kind == "snapshots":
        return g, Medium(343.0, 1.2), src, Sensors(probes=[(30, 20)], snapshot_every=20), Edges(thickness_cells=6)
    if kind == "late_phasors":  # phasors summed after a start step only (where Sensors has that option)
        try:
            late = Sensors(probes=[(30, 20)], phasor_cells=[(28, 25), (33, 18)], phasor_from_step=40)
        except TypeError:
            pytest.skip("this version's Sensors has no phasor_from_step")
        return g, Medium(343.0, rho), src, late, Edges(thickness_cells=6)
    raise AssertionError(kind)


KINDS = [
    "homogeneous",
    "conservative",
    "conservative+pml",
    "homogeneous+pml",
    "speed_zero+sponge",
    "absorbing",
    "absorbing+pml",
    "snapshots",
    "late_phasors",
]


def _compare(ref, got, dtype, n_steps=N):
    eps = float(jnp.finfo(jnp.dtype(dtype)).eps)
    peak = float(jnp.max(ref.peak_history))
    assert np.isfinite(peak) and peak > 1e-3
    tol = n_steps * 16 * eps * peak
    pairs = [
        ("pressure", ref.final.pressure, got.final.pressure),
        ("probes", ref.probes, got.probes),
        ("peak history", ref.peak_history, got.peak_history),
        ("snapshots", ref.snapshots, got.snapshots),
        ("p_max", ref.p_max, got.p_max),
        ("p_rms", ref.p_rms, got.p_rms),
    ]
    for name, a, b in pairs:
        assert (a is None) == (b is None), name
        if a is not None:
            err = float(jnp.max(jnp.abs(a - b)))
            assert err <= tol, f"{name}: {err:.3g} > {tol:.3g}"
    if ref.phasors is not None:  # sums over n_steps values: n_steps times the field tolerance
        err = float(jnp.max(jnp.abs(ref.phasors - got.phasors)))
        assert err <= n_steps * tol, f"phasors: {err:.3g}"
    if ref.arrival is not None:  # first step above the threshold: equal unless a value sits within tol of it
        assert int(jnp.sum(ref.arrival != got.arrival)) == 0


@pytest.mark.parametrize("dtype", ["float32", "float64"])
@pytest.mark.parametrize("kind", KINDS)
def test_native_equals_jax(kind, dtype):
    g, medium, src, sens, edges = _scene(kind, dtype)
    ref = simulate(g, medium, src, sens, n_steps=N, edges=edges, backend="jax", checkpoint=10)
    got = simulate(g, medium, src, sens, n_steps=N, edges=edges, backend="native", checkpoint=10)
    _compare(ref, got, dtype)


def test_axisymmetric_lattice_runs_natively():
    """The rz lattice (metric coefficients, velocity sources, the r_hi PML's cylindrical
    correction) runs on the same kernels."""
    try:
        g = _grid("float32", kind="rz")
    except TypeError:
        pytest.skip("this version has no axisymmetric grids")
    src = PointSources(
        cells=[(10, j) for j in range(6)],
        signal=ToneBurst(50e3, 2),
        weights=jnp.ones(6),
        lags_s=jnp.zeros(6),
        injection="velocity",
    )
    sens = Sensors(probes=[(30, 0), (36, 12)], phasor_cells=[(28, 25), (33, 18)])
    medium = Medium(343.0, jnp.where(X > 30, 2.0, 1.2), rigid=(X > 42).astype(jnp.float64))
    for edges in (
        Edges.axisymmetric("rigid", "rigid", "rigid"),
        Edges.axisymmetric("rigid", "pml", "pml", thickness_cells=6),
    ):
        assert native.why_not(Stepper.build(g, medium, src, sens, edges)) is None
        ref = simulate(g, medium, src, sens, n_steps=N, edges=edges, backend="jax")
        got = simulate(g, medium, src, sens, n_steps=N, edges=edges, backend="native")
        _compare(ref, got, "float32")


@pytest.mark.parametrize("dtype", ["float32", "float64"])
def test_axisymmetric_air_ring_form_equals_jax(dtype):
    """Air on an rz grid with rigid edges: the kernels' ring form (the metric's two factors sum
    to 2 inside a row, so the update is the unit stencil with two multiplies) against the XLA loop,
    to the rounding tolerance of `_compare`, sources on the axis and off it, probes and phasors."""
    g = _grid(dtype, kind="rz")
    src = PointSources(
        cells=[(10, j) for j in range(6)] + [(20, 30)],
        signal=ToneBurst(50e3, 2),
        weights=jnp.ones(7),
        lags_s=jnp.zeros(7),
    )
    sens = Sensors(probes=[(30, 0), (36, 12)], phasor_cells=[(28, 25), (33, 18)], p_max=True)
    edges = Edges.axisymmetric("rigid", "rigid", "rigid")
    assert native.why_not(Stepper.build(g, Medium(343.0, 1.2), src, sens, edges)) is None
    ref = simulate(g, Medium(343.0, 1.2), src, sens, n_steps=N, edges=edges, backend="jax")
    got = simulate(g, Medium(343.0, 1.2), src, sens, n_steps=N, edges=edges, backend="native")
    _compare(ref, got, dtype)


@pytest.mark.parametrize("kind", ["conservative", "conservative+pml"])
def test_threads_and_blocking_do_not_change_results(kind, monkeypatch):
    g, medium, src, sens, edges = _scene(kind, "float32")
    st = Stepper.build(g, medium, src, sens, edges)
    out = []
    for threads, levels, schedule in (
        (1, 1, "pipeline"),
        (3, 5, "pipeline"),
        (2, 64, "pipeline"),
        (7, 2, "pipeline"),
        (2, 8, "bands"),
        (5, 8, "bands"),
    ):
        monkeypatch.setenv("DIFFLATTICE_NATIVE_THREADS", str(threads))
        monkeypatch.setenv("DIFFLATTICE_NATIVE_LEVELS", str(levels))
        monkeypatch.setenv("DIFFLATTICE_NATIVE_SCHEDULE", schedule)
        r = eqx.filter_jit(lambda s: run(s, N, backend="native"))(st)  # traced anew: reads the settings
        out.append(r)
    for r in out[1:]:
        for name in ("pressure", "probes", "phasors", "p_max", "p_rms", "arrival"):
            a = r.final.pressure if name == "pressure" else getattr(r, name)
            b = out[0].final.pressure if name == "pressure" else getattr(out[0], name)
            np.testing.assert_array_equal(np.asarray(a), np.asarray(b), err_msg=name)


def test_concurrent_runs_from_two_threads_equal_sequential_ones(monkeypatch):
    """The kernels' worker threads persist between calls and take one call at a time; a call made
    while another thread's call holds them starts its own threads. Runs of two scenes from two
    Python threads at once (several rounds, so calls overlap) equal the same runs made one after
    the other, bitwise."""
    import threading

    monkeypatch.setenv("DIFFLATTICE_NATIVE_THREADS", "2")
    scenes = [Stepper.build(*_scene(k, "float32")) for k in ("conservative", "conservative+pml")]
    fns = [eqx.filter_jit(lambda s: run(s, N, backend="native").final.pressure) for _ in scenes]
    ref = [np.asarray(f(s)) for f, s in zip(fns, scenes)]
    got: list[list] = [[], []]
    errors = []

    def work(k):
        try:
            for _ in range(6):
                got[k].append(np.asarray(fns[k](scenes[k])))
        except Exception as e:  # re-raised below
            errors.append(e)

    threads = [threading.Thread(target=work, args=(k,)) for k in range(2)]
    for t in threads:
        t.start()
    for t in threads:
        t.join()
    assert not errors, errors
    for k in range(2):
        assert len(got[k]) == 6
        for a in got[k]:
            np.testing.assert_array_equal(a, ref[k])


def _uses_native(fn, *args) -> bool:
    text = str(jax.make_jaxpr(fn)(*args))
    return "difflattice_leapfrog" in text or "difflattice_layered" in text


def test_auto_runs_native_where_supported_and_falls_back_elsewhere():
    g = _grid("float32")
    src = line_transducer(g, (14 * g.dx_m, 20 * g.dx_m), n_cells=5, signal=ToneBurst(50e3, 2))
    ok = Stepper.build(g, Medium(343.0, 1.2), src, SENS, Edges(thickness_cells=6))
    assert _uses_native(lambda s: run(s, 20).final.pressure, ok)
    assert not _uses_native(lambda s: run(s, 20, backend="jax").final.pressure, ok)
    st = Stepper.build(g, Medium(343.0, 1.2), src, SENS, Edges.all("mur"))
    assert "Mur edges" in native.why_not(st)
    assert not _uses_native(lambda s: run(s, 20).final.pressure, st)
    a = run(st, 20).final.pressure
    b = run(st, 20, backend="jax").final.pressure
    np.testing.assert_array_equal(np.asarray(a), np.asarray(b))  # the same JAX loop
    with pytest.raises(ValueError, match="Mur edges"):
        run(st, 20, backend="native")
    with pytest.raises(ValueError, match="backend"):
        run(ok, 20, backend="fortran")


def test_paper_model_falls_back():
    g = _grid("float32")
    src = line_transducer(g, (14 * g.dx_m, 20 * g.dx_m), n_cells=5, signal=ToneBurst(50e3, 2))
    st = Stepper.build(
        g, Medium(343.0, 1.2, rigid=(X > 40).astype(jnp.float32), boundary_model="paper"), src, SENS, Edges.all("rigid")
    )
    assert "paper" in native.why_not(st)
    assert not _uses_native(lambda s: run(s, 20).final.pressure, st)


def test_gradients_through_native_runs_equal_jax_autodiff():
    """jax.grad and jax.jvp of a native run are the JAX loop's derivatives (float64, 1e-6)."""
    g = _grid("float64")
    sens = Sensors(probes=[(30, 20), (36, 12)], phasor_cells=[(28, 25), (33, 18), (40, 30)])

    def loss(w, lag, c, backend):
        src = line_transducer(
            g, (14 * g.dx_m, 20 * g.dx_m), n_cells=5, signal=ToneBurst(50e3, 2), weights=w, lags_s=lag
        )
        r = simulate(
            g,
            Medium(c, jnp.where(X > 30, 2.0, 1.2)),
            src,
            sens,
            n_steps=60,
            edges=Edges(thickness_cells=6),
            backend=backend,
            checkpoint=10,
        )
        return (
            jnp.sum(r.probes**2) + jnp.sum(jnp.abs(r.phasors) ** 2) * 1e-3 + jnp.sum(r.final.pressure * jnp.sin(X / 5))
        )

    w, lag = jnp.linspace(0.8, 1.2, 5), jnp.linspace(0.0, 3e-6, 5)
    c = 343.0 - 20.0 * jnp.exp(-((X - 26) ** 2 + (jnp.arange(40.0)[None] - 20) ** 2) / 30)
    assert _uses_native(lambda w: loss(w, lag, c, "auto"), w)  # the value alone runs natively
    v_ref, g_ref = jax.value_and_grad(loss, argnums=(0, 1, 2))(w, lag, c, "jax")
    v_nat, g_nat = jax.value_and_grad(loss, argnums=(0, 1, 2))(w, lag, c, "auto")
    assert abs(float(v_nat - v_ref)) <= 1e-6 * abs(float(v_ref))
    for name, a, b in zip(("weights", "lags", "speed map"), g_nat, g_ref):
        scale = float(jnp.max(jnp.abs(b)))
        assert scale > 0 and float(jnp.max(jnp.abs(a - b))) <= 1e-6 * scale, name
    t_ref = jax.jvp(lambda w: loss(w, lag, c, "jax"), (w,), (jnp.ones_like(w),))[1]
    t_nat = jax.jvp(lambda w: loss(w, lag, c, "auto"), (w,), (jnp.ones_like(w),))[1]
    assert abs(float(t_nat - t_ref)) <= 1e-6 * abs(float(t_ref))
    # and the forward value of the native loop itself agrees with JAX's, also under vmap
    assert abs(float(loss(w, lag, c, "native") - v_ref)) <= 1e-9 * abs(float(v_ref))
    ws = jnp.stack([w, 0.5 * w])
    batched = jax.vmap(lambda w_: loss(w_, lag, c, "native"))(ws)
    np.testing.assert_allclose(np.asarray(batched), [float(v_ref), float(loss(0.5 * w, lag, c, "jax"))], rtol=1e-9)


def test_cells_outside_the_grid_raise_at_run_time():
    g = _grid("float32")

    @jax.jit
    def f(ix):
        cells = jnp.stack([ix, jnp.asarray(20)])[None]
        src = PointSources(cells=cells, signal=ToneBurst(50e3, 2), weights=jnp.ones(1), lags_s=jnp.zeros(1))
        return run(
            Stepper.build(g, Medium(343.0, 1.2), src, Sensors(), Edges.all("rigid")), 10, backend="native"
        ).final.pressure

    assert np.isfinite(np.asarray(f(jnp.asarray(10)))).all()
    with pytest.raises(Exception, match="outside the grid"):
        jax.block_until_ready(f(jnp.asarray(500)))


def test_no_compiler_means_the_jax_loop_with_the_reason(monkeypatch, tmp_path):
    monkeypatch.setenv("DIFFLATTICE_NATIVE_CACHE", str(tmp_path))
    monkeypatch.setenv("CXX", "/nonexistent/c++")
    monkeypatch.setenv("PATH", str(tmp_path))  # no c++, g++ or clang++ on the path
    assert "no C++ compiler" in build._load()
    monkeypatch.setenv("DIFFLATTICE_NATIVE", "0")
    assert build._load() == "DIFFLATTICE_NATIVE=0"


def test_the_cached_library_is_reused():
    """Loading again (as a new process does) finds the compiled library by its hash: no rebuild."""
    assert isinstance(_LIB, build.Library)
    before = os.stat(_LIB.path).st_mtime_ns
    again = build._load()
    assert isinstance(again, build.Library) and again.path == _LIB.path
    assert os.stat(_LIB.path).st_mtime_ns == before


def test_adjoint_step_mode_is_the_transposed_operator():
    """The kernel's adjoint step (combine=2, the building block of a native backward pass):
    out = 2 a + L(K a) - h with L the flux stencil, for a conservative lattice."""
    from difflattice.lattice.operators import _face_coefficients, stencil

    g = _grid("float64")
    st = Stepper.build(
        g,
        Medium(343.0, jnp.where(X > 30, 2.0, 1.2), rigid=(X > 42).astype(jnp.float64)),
        (),
        Sensors(),
        Edges(x_lo="rigid", y_hi="rigid", x_hi="soft", y_lo="soft"),
    )
    lat = st.lattice
    rng = np.random.default_rng(1)
    a = jnp.asarray(rng.standard_normal(SHAPE))
    h = jnp.asarray(rng.standard_normal(SHAPE))
    bx, by = _face_coefficients(lat, SHAPE, jnp.float64)
    e = jnp.zeros((0,), jnp.float64)
    cells = jnp.zeros((0, 2), jnp.int32)
    args = [
        a,
        h,
        jnp.asarray(lat.K),
        bx,
        by,
        e,
        e,
        e,
        e,
        e,
        cells,
        jnp.zeros((0,), jnp.int32),
        jnp.zeros((1, 0)),
        cells,
        cells,
        cells,
        jnp.zeros(1),
        jnp.zeros(1),
        e,
        e,
        e,
        e,
        jnp.zeros((0,), jnp.int32),
        jnp.asarray(0, jnp.int32),
    ]
    shapes = (
        [jax.ShapeDtypeStruct(SHAPE, jnp.float64)] * 2
        + [jax.ShapeDtypeStruct((1, 0), jnp.float64)]
        + [jax.ShapeDtypeStruct((0,), jnp.float64)] * 4
        + [jax.ShapeDtypeStruct((0,), jnp.int32)]
    )
    out = jax.ffi.ffi_call("difflattice_leapfrog", shapes)(
        *args,
        n_steps=np.int64(1),
        threads=np.int64(2),
        levels=np.int64(1),
        bands=np.int64(0),
        combine=np.int64(2),
        stencil=np.int64(0),
        eta=0.0,
        threshold=0.0,
    )
    new, prev = out[0], out[1]
    ref = 2 * a + stencil(lat, lat.K * a) - h
    np.testing.assert_allclose(np.asarray(new), np.asarray(ref), rtol=0, atol=1e-12 * float(jnp.abs(ref).max()))
    np.testing.assert_array_equal(np.asarray(prev), np.asarray(a))  # (a, h) -> (new, a): the step's pair


def test_bench_refuses_a_busy_machine_and_computes_ratios(monkeypatch):
    """`difflattice bench`: a 1-minute load above 1 is refused unless forced; the ratios are the
    MLUPS quotients of the same case and grid."""
    from difflattice.apps import bench

    monkeypatch.setattr(os, "getloadavg", lambda: (3.0, 2.0, 1.0))
    with pytest.raises(RuntimeError, match="load average 3.00") as refused:
        bench.bench()
    assert "difflattice bench --force" in str(refused.value)  # the way to measure anyway
    rows = [
        {"case": "homogeneous", "grid": "840x630", "impl": "native", "mlups": 6000.0},
        {"case": "homogeneous", "grid": "840x630", "impl": "numba-1thread", "mlups": 4000.0},
        {"case": "full", "grid": "840x630", "impl": "native", "mlups": 1800.0},
    ]
    ratios = {r["ratio"]: r["value"] for r in bench._ratios(rows)}
    assert ratios["native/numba-1thread"] == 1.5
    assert ratios["full/homogeneous (native)"] == 0.3


def _iso_scene(kind, dtype):
    """(grid, medium, sources, sensors, edges) of isotropic-stencil scenes on uniform faces."""
    g = make_grid(
        frequency_hz=50e3,
        cells_per_wavelength=10,
        c_max_m_s=343.0,
        shape=SHAPE,
        dtype=dtype,
        kind="rz" if kind.startswith("rz") else "2d",
        stencil="isotropic",
    )
    src = PointSources(
        cells=[(10, j) for j in range(6)] + [(20, 30)],
        signal=ToneBurst(50e3, 2),
        weights=jnp.linspace(0.7, 1.3, 7),
        lags_s=jnp.zeros(7),
    )
    if kind == "rz rigid":
        return g, Medium(343.0, 1.2), src, SENS, Edges.axisymmetric("rigid", "rigid", "rigid")
    if kind == "rz soft+sponge":
        return g, Medium(343.0, 1.2), src, SENS, Edges.axisymmetric("soft", "sponge", "soft", thickness_cells=6)
    if kind == "rz pml":
        return g, Medium(343.0, 1.2), src, SENS, Edges.axisymmetric("rigid", "pml", "pml", thickness_cells=6)
    if kind == "2d pml+absorbing":
        return (
            g,
            Medium(343.0, 1.2, absorption_db_per_m=3.0),
            src,
            SENS,
            Edges(x_lo="soft", y_lo="rigid", thickness_cells=6),
        )
    rigid = ((X > 30) & (X < 35) & (jnp.arange(40.0)[None, :] > 5) & (jnp.arange(40.0)[None, :] < 25)).astype(
        jnp.float64
    )
    heavy = jnp.where(X > 38, 2.0, 1.2)
    if kind == "rz obstacle+density":  # face-conductance arrays (cut cells, a density step)
        return g, Medium(343.0, heavy, rigid=rigid), src, SENS, Edges.axisymmetric("rigid", "rigid", "soft")
    if kind == "rz obstacle+pml":
        return (
            g,
            Medium(343.0, heavy, rigid=rigid),
            src,
            SENS,
            Edges.axisymmetric("rigid", "pml", "pml", thickness_cells=6),
        )
    if kind == "2d obstacle+speed map+pml":
        medium = Medium(jnp.where(X < 8, 300.0, 343.0), heavy, rigid=rigid)
        return g, medium, src, SENS, Edges(x_lo="soft", y_lo="rigid", thickness_cells=6)
    if kind == "2d mixed":  # rigid and soft window sides, viscous absorption
        medium = Medium(343.0, 1.2, absorption_db_per_m=3.0)
        return g, medium, src, SENS, Edges(x_lo="soft", x_hi="rigid", y_lo="rigid", y_hi="soft")
    raise AssertionError(kind)


@pytest.mark.parametrize("dtype", ["float32", "float64"])
@pytest.mark.parametrize(
    "kind",
    [
        "rz rigid",
        "rz soft+sponge",
        "rz pml",
        "rz obstacle+density",
        "rz obstacle+pml",
        "2d mixed",
        "2d pml+absorbing",
        "2d obstacle+speed map+pml",
    ],
)
def test_isotropic_stencil_native_equals_jax(kind, dtype):
    """The isotropic (9-point) stencil runs natively, in air (the Mehrstellen row form, filtered
    PML face differences) and with face-conductance arrays (obstacles, density and speed maps:
    the filter's min(b_j, b_k) edge weights), and equals the XLA loop to the rounding tolerance of
    `_compare` (n_steps * 16 * eps * peak; the differences add linearly)."""
    g, medium, src, sens, edges = _iso_scene(kind, dtype)
    assert native.why_not(Stepper.build(g, medium, src, sens, edges)) is None
    ref = simulate(g, medium, src, sens, n_steps=N, edges=edges, backend="jax", checkpoint=10)
    got = simulate(g, medium, src, sens, n_steps=N, edges=edges, backend="native", checkpoint=10)
    _compare(ref, got, dtype)


def test_isotropic_stencil_threads_and_blocking_do_not_change_results(monkeypatch):
    g, medium, src, sens, edges = _iso_scene("rz rigid", "float32")
    st = Stepper.build(g, medium, src, sens, edges)
    out = []
    g, medium, src, sens, pml_edges = _iso_scene("rz pml", "float32")
    st_pml = Stepper.build(g, medium, src, sens, pml_edges)
    for stepper in (st, st_pml):
        out = []
        for threads, levels in ((1, 1), (3, 5), (2, 64)):
            monkeypatch.setenv("DIFFLATTICE_NATIVE_THREADS", str(threads))
            monkeypatch.setenv("DIFFLATTICE_NATIVE_LEVELS", str(levels))
            out.append(np.asarray(run(stepper, N, backend="native").final.pressure))
        assert all(np.array_equal(out[0], o) for o in out[1:])


def _adjoint_case(kind, dtype):
    """A loss of source weights and lags through `simulate(adjoint="lattice")` whose backward pass
    the kernel's adjoint step runs (no q_scale, keep, sponge or viscous term)."""
    sens = Sensors(probes=[(30, 20), (36, 12), (30, 20)], phasor_cells=[(28, 25), (33, 18), (40, 30)])
    kw = {"kind": "rz"} if kind == "rz" else {}
    g = _grid(dtype, **kw)
    zr = jnp.asarray(np.sin(np.arange(SHAPE[0] * SHAPE[1]).reshape(SHAPE) / 7.0), g.jnp_dtype)
    if kind == "rz":
        from difflattice.solver.sources import disc_transducer

        medium, edges = Medium(343.0, jnp.where(X > 30, 2.0, 1.2)), Edges.axisymmetric("rigid", "rigid", "rigid")

        def sources(w, lag):
            return disc_transducer(
                g, radius_m=5.3 * g.dx_m, n_rings=8, weights=w, lags_s=lag, signal=ToneBurst(50e3, 2)
            )

        n_src = 8
    else:
        medium = Medium(343.0, jnp.where(X > 30, 2.0, 1.2)) if kind == "density" else Medium(343.0, 1.2)
        edges = Edges.all("rigid")
        injection = "hard" if kind == "hard" else "soft"

        def sources(w, lag):
            return line_transducer(
                g,
                (14 * g.dx_m, 20 * g.dx_m),
                n_cells=5,
                signal=ToneBurst(50e3, 2),
                weights=w,
                lags_s=lag,
                injection=injection,
            )

        n_src = 5

    def loss(w, lag_us, backend):
        r = simulate(
            g, medium, sources(w, lag_us * 1e-6), sens, n_steps=N, edges=edges, adjoint="lattice", backend=backend
        )
        return jnp.sum(r.probes**2) + jnp.sum(jnp.abs(r.phasors) ** 2) * 1e-3 + jnp.sum(r.final.pressure * zr) * 0.1

    args = (jnp.linspace(0.8, 1.2, n_src).astype(g.jnp_dtype), jnp.linspace(0.0, 3.0, n_src).astype(g.jnp_dtype))
    return loss, args, sources, g, medium, sens, edges


@pytest.mark.parametrize("dtype", ["float64", "float32"])
@pytest.mark.parametrize("kind", ["homogeneous", "density", "hard", "rz"])
def test_native_lattice_adjoint_equals_the_jax_one(kind, dtype, monkeypatch):
    """`adjoint="lattice"` with the forward and the backward runs on the native kernels (the
    kernel's adjoint step carries x = a / V, the probes' and phasors' cotangents injected and the
    source cells recorded inside the loop) = the same reverse mode on the JAX loop. Both sum the
    same per-step terms in a different order: the per-step bound of the forward comparison (module
    docstring) applies to the cotangent fields, whose peak the gradient's scale bounds, so the
    tolerance is n_steps * 16 * eps relative to the largest gradient entry."""
    from difflattice.solver import adjoint as adj

    loss, args, sources, g, medium, sens, edges = _adjoint_case(kind, dtype)
    st = Stepper.build(g, medium, sources(*args), sens, edges)
    assert adj._native_backward(st) and native.why_not(st) is None
    calls = []
    real = adj._native_backward_pass
    monkeypatch.setattr(adj, "_native_backward_pass", lambda *a: calls.append(1) or real(*a))
    val, got = jax.value_and_grad(lambda w, lag: loss(w, lag, "auto"), argnums=(0, 1))(*args)
    assert calls, "the native backward pass did not run"
    ref_val, ref = jax.value_and_grad(lambda w, lag: loss(w, lag, "jax"), argnums=(0, 1))(*args)
    tol = N * 16 * float(jnp.finfo(dtype).eps)
    assert abs(float(val - ref_val)) <= tol * abs(float(ref_val))
    for name, a, b in zip(("weights", "lags"), got, ref):
        scale = float(jnp.abs(b).max())
        assert scale > 0, name
        err = float(jnp.abs(a - b).max())
        assert err <= tol * scale, f"{kind} {dtype} {name}: {err:.3g} vs scale {scale:.3g} (tol {tol:.2g})"


@pytest.mark.parametrize(
    "kind, dtype, segment",
    [(k, d, 40) for k in ("plane", "plane-hard", "rz", "rz-disc") for d in ("float64", "float32")]
    + [("plane", "float32", None)],
)
def test_native_lattice_adjoint_coefficient_gradients(kind, dtype, segment, monkeypatch):
    """Gradients w.r.t. a speed map and a density map (every coefficient the kernels' adjoint
    computes: K and both face conductances; on the rz lattice with the ring metric) and the
    sources, with the backward pass on `difflattice_adjoint_chunk` (fields stepped back segment by
    segment, cotangents fused into the adjoint step) = the JAX lattice adjoint's, to the module's
    rounding bound relative to each gradient's largest entry. Segments of 40 steps over chunks of
    10 and 97 steps: two whole segments from saved ends, then 17 steps (a chunk and the remainder)
    from the final fields; the default segment (256 steps): the whole run from the final fields."""
    from difflattice.solver import adjoint as adj
    from difflattice.solver.native import kernels
    from difflattice.solver.sources import disc_transducer

    if segment is not None:
        monkeypatch.setattr(adj, "NATIVE_SEGMENT_STEPS", segment)
    jax.clear_caches()  # the segment is read while tracing: no program traced by another case

    rz = kind.startswith("rz")
    g = _grid(dtype, kind="rz") if rz else _grid(dtype)
    dt = g.jnp_dtype
    sens = Sensors(probes=[(30, 20), (36, 12)], phasor_cells=[(28, 25), (33, 18)])
    bump = jnp.exp(-((X - 26) ** 2 + (jnp.arange(40.0)[None] - 20) ** 2) / 30).astype(dt)
    if kind == "rz-disc":  # velocity injection: the speed map also scales the source
        src = disc_transducer(g, radius_m=4.6 * g.dx_m, n_rings=5, signal=ToneBurst(50e3, 2))
    else:
        injection = "hard" if kind == "plane-hard" else "soft"
        src = line_transducer(g, (14 * g.dx_m, 20 * g.dx_m), n_cells=5, signal=ToneBurst(50e3, 2), injection=injection)
    edges = Edges.axisymmetric("rigid", "rigid", "rigid") if rz else Edges.all("rigid")

    def loss(w, c_scale, rho_scale, backend):
        s = eqx.tree_at(lambda s: s.weights, src, w)
        med = Medium(343.0 - 20.0 * c_scale * bump, 1.2 + 0.8 * rho_scale * bump)
        r = simulate(g, med, s, sens, n_steps=N, edges=edges, adjoint="lattice", checkpoint=10, backend=backend)
        return jnp.sum(r.probes**2) + jnp.sum(jnp.abs(r.phasors) ** 2) * 1e-3

    calls = []
    real = kernels._Chunk.adjoint_chunk
    monkeypatch.setattr(kernels._Chunk, "adjoint_chunk", lambda *a, **k: calls.append(1) or real(*a, **k))
    args = (jnp.linspace(0.8, 1.2, 5).astype(dt), jnp.asarray(1.0, dt), jnp.asarray(1.0, dt))
    got = jax.grad(lambda *a: loss(*a, "native"), argnums=(0, 1, 2))(*args)
    assert calls, "the native chunked backward pass did not run"
    ref = jax.grad(lambda *a: loss(*a, "jax"), argnums=(0, 1, 2))(*args)
    tol = N * 16 * float(jnp.finfo(dt).eps)
    for name, a, b in zip(("weights", "speed", "density"), got, ref):
        scale = float(jnp.abs(b).max())
        assert scale > 0, name
        err = float(jnp.abs(a - b).max())
        assert err <= tol * scale, f"{kind} {dtype} {name}: {err:.3g} vs scale {scale:.3g} (tol {tol:.2g})"


def test_native_lattice_adjoint_reconstructs_the_forward_field_over_a_long_chunk():
    """The chunked backward pass steps the forward field back from the chunk's end; over one chunk
    of the whole run (300 steps, float32) its rounding stays within the forward comparison's bound
    (n_steps x 16 eps relative): the speed-map gradient against the float64 JAX reference."""
    n = 300
    sens = Sensors(probes=[(30, 20), (36, 12)])

    def grad(dtype, checkpoint, backend):
        g = _grid(dtype)
        src = line_transducer(g, (14 * g.dx_m, 20 * g.dx_m), n_cells=5, signal=ToneBurst(50e3, 3))
        bump = jnp.exp(-((X - 26) ** 2 + (jnp.arange(40.0)[None] - 20) ** 2) / 30).astype(g.jnp_dtype)

        def loss(c_scale):
            med = Medium(343.0 - 20.0 * c_scale * bump, jnp.where(X > 30, 2.0, 1.2).astype(g.jnp_dtype))
            r = simulate(
                g,
                med,
                src,
                sens,
                n_steps=n,
                edges=Edges.all("rigid"),
                adjoint="lattice",
                checkpoint=checkpoint,
                backend=backend,
            )
            return jnp.sum(r.probes**2)

        return float(jax.grad(loss)(jnp.asarray(1.0, g.jnp_dtype)))

    ref = grad("float64", None, "jax")
    got = grad("float32", n, "native")
    assert ref != 0
    assert abs(got - ref) <= n * 16 * float(jnp.finfo(jnp.float32).eps) * abs(ref), (got, ref)


def test_a_build_says_so_on_stderr(monkeypatch, tmp_path, capsys):
    """The one slow start of a machine (compiling the kernels) prints a line when it begins and
    when it ends. A stand-in compiler writes an empty file: the build 'succeeds', loading fails."""
    fake = tmp_path / "fake-c++"
    fake.write_text('#!/bin/sh\nfor a; do out="$b"; b="$a"; done\n: > "$b"\n')
    fake.chmod(0o755)
    monkeypatch.setenv("DIFFLATTICE_NATIVE_CACHE", str(tmp_path / "cache"))
    monkeypatch.setenv("CXX", str(fake))
    reason = build._load()
    err = capsys.readouterr().err
    assert "compiling the native CPU kernels" in err and "compiled in" in err
    assert isinstance(reason, str) and "loading" in reason


@pytest.mark.parametrize("dtype", ["float32", "float64"])
def test_a_pml_state_continues_across_backends(dtype):
    """The layered PML state (P, P(n-1) and the layer boxes' split fields) means the same to both
    loops: 40 steps of one and 57 of the other equal 97 of the JAX loop (rounding, as `_compare`)."""
    g, medium, src, sens, edges = _scene("conservative+pml", dtype)
    st = Stepper.build(g, medium, src, sens, edges)
    ref = run(st, N, backend="jax")
    for first, second in (("jax", "native"), ("native", "jax")):
        a = run(st, 40, backend=first)
        b = run(st, N - 40, state=a.final, backend=second)
        eps = float(jnp.finfo(jnp.dtype(dtype)).eps)
        tol = N * 16 * eps * float(jnp.max(ref.peak_history))
        assert float(jnp.max(jnp.abs(b.final.pressure - ref.final.pressure))) <= tol
        # parts and fluxes: pressures and sums of pressure differences, rounded on the pressure's scale
        for fa, fb in zip(jax.tree_util.tree_leaves(b.final.layers), jax.tree_util.tree_leaves(ref.final.layers)):
            assert float(jnp.max(jnp.abs(fa - fb))) <= tol
