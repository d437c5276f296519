"""Eager lattice runs on the native kernels (`simulate`, issue 30): compiled at XLA's backend
optimisation level 0 (`loop.NATIVE_GLUE_OPTIONS`) they give the same bits as at the default level;
kept whole on disk (`solver.program_cache` with the kernels declared), a new process loads the
program and gets the same bits; a corrupt entry is recompiled, another kernel setting is another
program, and kernels that are not registered mean no load and no store (the ordinary path runs)."""

from __future__ import annotations

import os
import subprocess
import sys
import textwrap
from pathlib import Path

import jax
import jax.numpy as jnp
import numpy as np
import pytest

from difflattice.lattice import Edges
from difflattice.lattice.grid import make_grid
from difflattice.lattice.medium import Medium
from difflattice.solver import Sensors, loop, native, simulate
from difflattice.solver import program_cache as pc
from difflattice.solver.sources import ToneBurst, disc_transducer, line_transducer

_LIB = native.load()
pytestmark = pytest.mark.skipif(isinstance(_LIB, str), reason=f"native kernels unavailable: {_LIB}")

SENS = Sensors(probes=[(30, 20), (36, 12)], phasor_cells=[(28, 25), (33, 18), (40, 30)], p_max=True, p_rms=True)


def _scene(dtype: str = "float64", conservative: bool = False):
    """A PML window with a line source, probes, phasors and field statistics (what a fit's
    transfer run records, and more); `conservative`: with speed and density maps and obstacles."""
    g = make_grid(frequency_hz=50e3, cells_per_wavelength=10, c_max_m_s=343.0, shape=(48, 40), dtype=dtype)
    w, lags = jnp.linspace(0.5, 1.0, 5), jnp.linspace(0.0, 2e-6, 5)
    src = line_transducer(g, (14 * g.dx_m, 20 * g.dx_m), n_cells=5, signal=ToneBurst(50e3, 2), weights=w, lags_s=lags)
    if not conservative:
        return g, Medium(343.0, 1.2), src, SENS
    x = jnp.arange(48.0)[:, None] * jnp.ones((1, 40))
    c, rho = jnp.where(x > 20, 343.0, 300.0), jnp.where(x > 30, 2.0, 1.2)
    rigid, soft = (x > 42).astype(jnp.float64), ((x < 4) & (x > 1)).astype(jnp.float64)
    return g, Medium(c, rho, rigid=rigid, soft=soft), src, SENS


def _run(dtype: str = "float64"):
    g, m, src, sens = _scene(dtype)
    return simulate(g, m, src, sens, n_steps=97, edges=Edges(thickness_cells=6))


def _arrays(res) -> list[np.ndarray]:
    return [np.asarray(x) for x in jax.tree_util.tree_leaves(res) if hasattr(x, "shape")]


def _same(a, b) -> bool:
    xa, xb = _arrays(a), _arrays(b)
    return len(xa) == len(xb) > 0 and all(x.dtype == y.dtype and np.array_equal(x, y) for x, y in zip(xa, xb))


@pytest.fixture
def cache(tmp_path, monkeypatch):
    """The cache on, in a directory of its own, with an empty memory (what a new process sees)."""
    where = tmp_path / "programs"
    monkeypatch.setattr(pc, "cache_dir", lambda: where)
    fresh = pc.CachedProgram(loop._simulate_fn, loop.NATIVE_GLUE_OPTIONS, kernels=loop._NATIVE_KERNELS)
    monkeypatch.setattr(loop, "_simulate_native_cached", fresh)
    return where


@pytest.mark.parametrize("conservative", [False, True], ids=["homogeneous", "conservative"])
@pytest.mark.parametrize("dtype", ["float64", "float32"])
def test_native_glue_at_level_0_gives_the_same_bits(dtype, conservative):
    """On a plane grid the optimisation level changes the compile time of the glue round the
    kernels, not what it computes: the run at level 0 equals the same program at XLA's default
    level bit for bit."""
    g, m, src, sens = _scene(dtype, conservative)
    stepper = loop.Stepper.build(g, m, src, sens, Edges(thickness_cells=6))
    args = (stepper, 97, None, None, None, "autodiff", False, "auto")
    at_default = loop._simulate(*args, speed_check=False)
    at_zero = loop._simulate_native(*args, speed_check=False)
    assert at_zero.backend == at_default.backend == "native"
    assert _same(at_zero, at_default)
    if not conservative:
        assert _same(_run(dtype), at_default)  # `simulate` called eagerly takes the level-0 program


def test_an_rz_run_keeps_the_default_level_and_is_stored(cache):
    """Level 0 changed an rz run by rounding: there the stored program is compiled at XLA's
    default level, and gives `_simulate`'s bits."""
    g = make_grid(
        frequency_hz=40e3, cells_per_wavelength=12, c_max_m_s=343.0, shape=(80, 40), dtype="float32", kind="rz"
    )
    w, lags = jnp.linspace(0.5, 1.0, 8, dtype=jnp.float32), jnp.linspace(0.0, 3e-6, 8, dtype=jnp.float32)
    src = disc_transducer(
        g, radius_m=8 * g.dx_m, z_m=0.0, n_rings=8, signal=ToneBurst(40e3, 4.0), weights=w, lags_s=lags
    )
    edges = Edges.axisymmetric("rigid", "pml", "pml", thickness_cells=12)
    res = simulate(g, Medium(343.0, 1.2), src, Sensors(), n_steps=90, edges=edges)
    stepper = loop.Stepper.build(g, Medium(343.0, 1.2), src, Sensors(), edges)
    ref = loop._simulate(stepper, 90, None, None, None, "autodiff", False, "auto", speed_check=False)
    assert res.backend == ref.backend == "native" and _same(res, ref)
    assert len(list(cache.glob("*.prog"))) == 1


def test_a_native_run_is_stored_loaded_and_gives_the_same_bits(cache, monkeypatch):
    first = _run()
    (path,) = cache.glob("*.prog")
    fresh = pc.CachedProgram(loop._simulate_fn, loop.NATIVE_GLUE_OPTIONS, kernels=loop._NATIVE_KERNELS)
    monkeypatch.setattr(loop, "_simulate_native_cached", fresh)
    loads = []
    real = pc._load
    monkeypatch.setattr(pc, "_load", lambda p, n: loads.append(real(p, n)) or loads[-1])
    second = _run()
    assert loads and loads[0] is not None  # read from disk
    assert _same(first, second) and second.backend == "native"
    # a preload (which registers no kernels) leaves it to its CachedProgram
    assert pc._from_bytes(path.read_bytes(), None, path) is None


@pytest.mark.parametrize("garbage", [b"", b"\x80\x04K\x01."], ids=["empty", "an int"])
def test_a_corrupt_entry_is_recompiled(cache, monkeypatch, garbage):
    first = _run()
    (path,) = cache.glob("*.prog")
    path.write_bytes(garbage)
    fresh = pc.CachedProgram(loop._simulate_fn, loop.NATIVE_GLUE_OPTIONS, kernels=loop._NATIVE_KERNELS)
    monkeypatch.setattr(loop, "_simulate_native_cached", fresh)
    assert _same(_run(), first)  # no error: compiled again
    assert path.read_bytes() != garbage and path.stat().st_size > 1000  # and rewritten whole


def test_another_thread_count_is_another_program(cache, monkeypatch):
    """The kernels' settings are read while tracing (they are the FFI call's attributes): part of
    the key, though no argument shows them."""
    _run()
    monkeypatch.setenv("DIFFLATTICE_NATIVE_THREADS", "1")
    fresh = pc.CachedProgram(loop._simulate_fn, loop.NATIVE_GLUE_OPTIONS, kernels=loop._NATIVE_KERNELS)
    monkeypatch.setattr(loop, "_simulate_native_cached", fresh)
    _run()
    assert len(list(cache.glob("*.prog"))) == 2


def test_kernels_not_registered_mean_no_load_and_no_store(cache, monkeypatch):
    """Deserialising a program whose FFI targets are not registered fails ("No FFI handler
    registered"); `Kernels.ready` is asked first, and where it says no, the ordinary path runs."""
    _run()
    (path,) = cache.glob("*.prog")
    absent = pc.Kernels(loop._NATIVE_KERNELS.targets, lambda: False, loop._NATIVE_KERNELS.key)
    prog = pc.CachedProgram(loop._simulate_fn, loop.NATIVE_GLUE_OPTIONS, kernels=absent)
    loads = []
    monkeypatch.setattr(pc, "_load", lambda p, n: loads.append(p))
    g, m, src, sens = _scene()
    stepper = loop.Stepper.build(g, m, src, sens, Edges(thickness_cells=6))
    args = (stepper, 97, None, None, None, "autodiff", False, "auto")
    assert prog(args, {"speed_check": False}) is NotImplemented
    assert not loads and list(cache.glob("*.prog")) == [path]


def test_a_program_with_an_undeclared_kernel_is_not_stored():
    """Only the targets a `CachedProgram` declares may be stored (beside LAPACK's)."""

    class Stub:
        _executable = type("E", (), {"_unloaded_executable": None})()

        def as_text(self):
            return 'x = f32[4] custom-call(y), custom_call_target="difflattice_layered"'

    with pytest.raises(ValueError, match="difflattice_layered"):
        pc._serialise(Stub(), None, 1)
    other = pc.Kernels(frozenset({"difflattice_leapfrog"}), lambda: True, str)
    with pytest.raises(ValueError, match="difflattice_layered"):
        pc._serialise(Stub(), None, 1, other)


SCRIPT = textwrap.dedent(
    """
    import sys
    import numpy as np
    import jax
    jax.config.update("jax_enable_x64", True)
    from difflattice.lattice import Edges
    from difflattice.lattice.grid import make_grid
    from difflattice.lattice.medium import Medium
    from difflattice.solver import Sensors, simulate
    from difflattice.solver import program_cache as pc
    from difflattice.solver.sources import ToneBurst, disc_transducer, line_transducer

    where = pc.Path(sys.argv[1])
    pc.cache_dir = lambda: where
    loaded = []
    real = pc._load
    pc._load = lambda p, n: loaded.append(real(p, n)) or loaded[-1]
    g = make_grid(frequency_hz=50e3, cells_per_wavelength=10, c_max_m_s=343.0, shape=(48, 40))
    src = line_transducer(g, (14 * g.dx_m, 20 * g.dx_m), n_cells=5, signal=ToneBurst(50e3, 2))
    res = simulate(g, Medium(343.0, 1.2), src, Sensors(phasor_cells=[(28, 25), (33, 18)]), n_steps=97,
                   edges=Edges(thickness_cells=6))
    print("hit" if loaded and loaded[0] is not None else "miss", res.backend,
          np.asarray(res.phasors).tobytes().hex(), np.asarray(res.final.pressure).tobytes().hex())
    """
)


def test_a_new_process_loads_the_lattice_program_and_runs_it(tmp_path):
    """Loaded without tracing, the program must find the kernels' FFI targets (registered by
    `native.load` before the load) and give the same bits."""
    env = dict(os.environ, PYTHONPATH=str(Path(pc.__file__).resolve().parents[2]), DIFFLATTICE_PROGRAM_CACHE="1")
    runs = [
        subprocess.run(
            [sys.executable, "-c", SCRIPT, str(tmp_path)], capture_output=True, text=True, env=env, timeout=300
        )
        for _ in range(2)
    ]
    for r in runs:
        assert r.returncode == 0, r.stderr[-2000:]
    first, second = (r.stdout.split() for r in runs)
    assert first[:2] == ["miss", "native"] and second[:2] == ["hit", "native"]
    assert first[2:] == second[2:]


def test_the_jax_loop_keeps_its_program(cache):
    """A run the chooser gives to the JAX scan is `_simulate` (XLA's default level: the scan is
    the run time), and is not stored."""
    g, m, src, sens = _scene()
    res = simulate(g, m, src, sens, n_steps=40, edges=Edges(thickness_cells=6), backend="jax")
    stepper = loop.Stepper.build(g, m, src, sens, Edges(thickness_cells=6))
    ref = loop._simulate(stepper, 40, None, None, None, "autodiff", False, "jax", speed_check=False)
    assert res.backend == "jax" and _same(res, ref)
    assert not list(cache.glob("*.prog"))
