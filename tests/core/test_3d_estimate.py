"""The run estimator (`solver/estimate.py`): its memory model counted by hand for small cases,
the refusal of a run that does not fit, and bad input named."""

import math

import pytest

from difflattice.solver.estimate import (
    RUNTIME_OVERHEAD_BYTES,
    WORKING_SET_FACTOR,
    RunFeatures,
    RunTooLargeError,
    available_memory_bytes,
    check_fits,
    estimate_run,
    memory_breakdown,
)


def test_memory_model_by_hand():
    n = 10
    N = n**3
    faces = 3 * n * n * (n + 1)
    # homogeneous PML run, f32: 3 pressure parts + 3 face fluxes, working set factor, nothing else
    parts = memory_breakdown((n, n, n), 100, "float32", RunFeatures(pml=True))
    assert parts["fields"] == int(WORKING_SET_FACTOR * (3 * N + faces) * 4)
    assert parts["coefficients"] == 0 and parts["recordings"] == 0
    # leapfrog, f64, heterogeneous, probes and two slices
    f = RunFeatures(pml=False, heterogeneous=True, n_probes=5, snapshot_cells=n * n, n_snapshots=2)
    parts = memory_breakdown((n, n, n), 100, "float64", f)
    assert parts["fields"] == int(WORKING_SET_FACTOR * 2 * N * 8)
    assert parts["coefficients"] == (2 * N + faces) * 8
    assert parts["recordings"] == (5 * 100 + 2 * n * n) * 8
    nbytes, seconds = estimate_run((n, n, n), 100, "float64", {**f.__dict__, "mlups": 10.0})
    assert nbytes == sum(parts.values())
    assert seconds == pytest.approx(N * 100 / 10e6 + 4.0)
    # memory grows like the cell count: 256^3 f32 PML ~ 6 fields x 2 x 64 MiB
    b256, _ = estimate_run((256,) * 3, 2000, "float32", RunFeatures(mlups=50.0))
    assert b256 == pytest.approx(WORKING_SET_FACTOR * 6 * 256**3 * 4, rel=0.02)


def test_refusal_names_estimate_and_fix():
    nbytes, s = estimate_run((1024,) * 3, 10, "float64", RunFeatures(mlups=50.0))
    with pytest.raises(RunTooLargeError, match=r"1024 x 1024 x 1024.*Fix: fewer cells"):
        check_fits((1024,) * 3, 10, nbytes, available=8 * 2**30, seconds=s)
    check_fits(
        (64,) * 3,
        10,
        estimate_run((64,) * 3, 10, "float32", RunFeatures(mlups=50.0))[0],
        available=RUNTIME_OVERHEAD_BYTES + 2**30,
    )
    assert available_memory_bytes() > 0
    assert issubclass(RunTooLargeError, ValueError)


def test_bad_inputs():
    with pytest.raises(ValueError, match="unknown run features"):
        estimate_run((8, 8, 8), 10, "float32", {"pml": True, "snapshots": 3})
    with pytest.raises(ValueError, match="n_steps"):
        estimate_run((8, 8, 8), 0, "float32", RunFeatures(mlups=1.0))
    with pytest.raises(ValueError, match="dtype"):
        estimate_run((8, 8, 8), 10, "float16", RunFeatures(mlups=1.0))
    with pytest.raises(ValueError, match="mlups"):
        estimate_run((8, 8, 8), 10, "float32", RunFeatures(mlups=0.0))
    assert math.isfinite(estimate_run((8, 8), 10, "float32", RunFeatures(mlups=1.0))[1])


@pytest.mark.parametrize(
    "stencil,courant,edges_kind,maps",
    [
        ("standard", 0.57, "sponge", False),
        ("standard", 0.57, "pml", True),
        ("isotropic", 0.86, "sponge", True),
        ("isotropic", 0.86, "pml", False),
        ("wide", 0.595, "sponge", False),
        ("wide", 0.595, "sponge", True),
        ("wide", 0.595, "pml", True),
    ],
)
def test_run_memory_model_covers_xla(stencil, courant, edges_kind, maps):
    """The memory model against an independent figure: XLA's own account of the compiled run
    (arguments + temporaries + outputs, `Compiled.memory_analysis`) on a 56 x 44 x 36 grid (not one
    of the two `STENCIL_WORKING_ARRAYS` was measured on). The
    model must not fall short (it is what refuses a run before allocation) and must not exceed it
    by more than the working-set factor's headroom (x 2: the old and new state of a step); buffers
    of no grid size are not modelled (64 KiB allowed)."""
    import equinox as eqx
    import jax
    import numpy as np

    from difflattice.lattice.coefficients import Edges
    from difflattice.lattice.grid import make_grid
    from difflattice.lattice.medium import Medium
    from difflattice.solver.estimate import features_of
    from difflattice.solver.loop import run
    from difflattice.solver.stepper import Stepper

    shape, n = (56, 44, 36), 20
    grid = make_grid(
        frequency_hz=40e3,
        cells_per_wavelength=12,
        c_max_m_s=343.0,
        shape=shape,
        courant=courant,
        dtype="float32",
        kind="3d",
        stencil=stencil,
    )
    medium = Medium(343.0, 1.2)
    if maps:
        x = np.arange(shape[0], dtype=float).reshape((-1, 1, 1))
        wall = np.clip(x - 0.75 * shape[0], 0.0, 1.0) * np.ones(shape)
        medium = Medium(343.0, 1.2, rigid=jax.numpy.asarray(wall, grid.jnp_dtype))
    st = Stepper.build(grid, medium, edges=Edges.all(edges_kind, thickness_cells=6))
    ma = jax.jit(lambda s: run(s, n, backend="jax").final).lower(st).compile().memory_analysis()
    xla = ma.argument_size_in_bytes + ma.temp_size_in_bytes + ma.output_size_in_bytes - ma.alias_size_in_bytes
    model = sum(memory_breakdown(shape, n, "float32", features_of(st, n)).values())
    small = 64 * 1024  # buffers of no grid size (scalars, counters): not modelled, here ~0.2 KiB
    assert xla <= model + small and model <= 2.0 * xla, (model / xla, eqx.tree_pformat(features_of(st, n)))


def test_check_compiled_refuses_what_does_not_fit():
    import jax
    import jax.numpy as jnp

    from difflattice.solver.estimate import check_compiled

    compiled = jax.jit(lambda x: jnp.cumsum(x) * 2.0).lower(jnp.zeros(1 << 20, jnp.float32)).compile()
    need = check_compiled(compiled, (1 << 20,), 1, available=1 << 40)
    assert need is not None and need >= 4 << 20  # at least the 4 MiB output
    with pytest.raises(RunTooLargeError, match="allocates .* when it starts"):
        check_compiled(compiled, (1 << 20,), 1, available=1 << 20)


def test_throughput_measured_on_a_busy_machine_is_measured_again(monkeypatch):
    """A cached MLUPS taken at 4 x the core count in load is re-measured once the machine is quiet,
    and kept while it is still as busy."""
    import os

    from difflattice.solver import estimate as E

    cores = os.cpu_count() or 1
    busy = {"mlups": 47.0, "load_average": [4.0 * cores, 4.0 * cores, 4.0 * cores]}
    quiet = {"mlups": 379.0, "load_average": [0.3 * cores, 0.3, 0.3]}
    monkeypatch.setattr(os, "getloadavg", lambda: (0.5 * cores, 0.5, 0.5))
    assert E._measured_busier(busy) and not E._measured_busier(quiet)
    monkeypatch.setattr(os, "getloadavg", lambda: (4.0 * cores, 4.0, 4.0))
    assert not E._measured_busier(busy)
    assert not E._measured_busier({"mlups": 1.0})  # an entry without its load is kept
