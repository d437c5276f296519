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
