"""The benchmark's reference loops (benchmarks/reference_kernels.py, run by `difflattice bench
--reference` in their own venv) compute the lattice difflattice computes, so their MLUPS compare
like with like. Here their plain-Python forms run against difflattice's steppers on a small grid."""

import importlib.util
from pathlib import Path

import jax.numpy as jnp
import numpy as np
import pytest

from difflattice.lattice import Edges
from difflattice.lattice.grid import make_grid
from difflattice.lattice.medium import Medium
from difflattice.solver.loop import run
from difflattice.solver.stepper import Stepper

ROOT = Path(__file__).resolve().parents[2]


@pytest.fixture(scope="module")
def ref():
    spec = importlib.util.spec_from_file_location("reference_kernels", ROOT / "benchmarks" / "reference_kernels.py")
    assert spec is not None and spec.loader is not None
    mod = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(mod)
    return mod


def _impulse_run(kind: str, nx: int, ny: int, cell: tuple[int, int], steps: int) -> tuple[np.ndarray, float]:
    """difflattice's field after `steps` leapfrog steps from a unit impulse at `cell` (at rest
    before), rigid edges, float64; and the stepper's K."""
    g = make_grid(
        frequency_hz=50e3, cells_per_wavelength=20, c_max_m_s=343.0, shape=(nx, ny), dtype="float64", kind=kind
    )  # type: ignore[arg-type]
    e = Edges.axisymmetric("rigid", "rigid", "rigid") if kind == "rz" else Edges.all("rigid")
    st = Stepper.build(g, Medium(343.0, 1.2), (), edges=e)
    s0 = st.init()
    p0 = jnp.zeros((nx, ny)).at[cell].set(1.0)
    s0 = type(s0)(**{**{k: getattr(s0, k) for k in s0.__dataclass_fields__}, "p": p0})
    out = run(st, steps, state=s0, backend="jax")
    return np.asarray(out.final.pressure), float(st.lattice.K)


def test_rz_reference_loop_is_difflattices_rz_leapfrog(ref):
    """`rz_serial` (the numba rz kernels' arithmetic) equals difflattice's rz stepper to float64
    rounding, the axis included, while the impulse has not reached the window's edges (where the
    reference holds zero and difflattice reflects): 12 steps from r = 3 on a 40 x 30 grid reach
    rows 8..32 and rings 0..15. Tolerance: 12 steps of a few roundings of O(1) values, 1e-12."""
    nx, ny, steps, cell = 40, 30, 12, (20, 3)
    ours, K = _impulse_run("rz", nx, ny, cell, steps)
    ml, mh = ref.rz_metric(ny + 1, "float64")
    p = np.zeros((nx, ny + 1))
    q = np.zeros((nx, ny + 1))
    p[cell[0], cell[1] + 1] = 1.0  # column 0 is the reference's zero ghost
    P, _ = ref.rz_serial(p, q, K, 2.0 - 4.0 * K, steps, ml, mh)
    theirs = P[:, 1:]
    assert np.abs(ours).max() > 0.01 and np.abs(ours[:, 0]).max() > 1e-3  # the wave reached the axis
    assert np.abs(ours[:7]).max() == 0 and np.abs(ours[:, 16:]).max() == 0  # and not the edges
    np.testing.assert_allclose(theirs, ours, rtol=0, atol=1e-12)
    # without the metric (the plane weights, ones) the same loop differs: the check can fail
    p[:] = 0.0
    p[cell[0], cell[1] + 1] = 1.0
    ones = np.ones(ny + 1)
    flat, _ = ref.rz_serial(p, np.zeros((nx, ny + 1)), K, 2.0 - 4.0 * K, steps, ones, ones)
    assert np.abs(flat[:, 1:] - ours).max() > 1e-3


def test_2d_reference_loop_is_difflattices_leapfrog(ref):
    """`numpy_run` (the 2-D reference's arithmetic, which the numba kernels repeat) equals
    difflattice's 2-D leapfrog away from the edges, float64 rounding (1e-12)."""
    nx, ny, steps, cell = 40, 30, 10, (20, 15)
    ours, K = _impulse_run("2d", nx, ny, cell, steps)
    assert K == pytest.approx(ref.C2, rel=1e-3)  # the reference's c2: the paper's Courant number 0.707, squared
    p = np.zeros((nx, ny))
    p[cell] = 1.0
    P, _ = ref.numpy_run(p, np.zeros((nx, ny)), K, 2.0 - 4.0 * K, steps)
    assert np.abs(ours[:9]).max() == 0 and np.abs(ours[:, 26:]).max() == 0
    np.testing.assert_allclose(P, ours, rtol=0, atol=1e-12)


def test_bench_ratios_keep_the_lattices_apart():
    """`difflattice bench` labels rz cases by grid ("840x630 rz"), so a ratio never divides an rz
    figure by a 2-D one; the rz scene runs on the native kernels (no silent JAX fallback)."""
    from difflattice.apps import bench
    from difflattice.solver.native import why_not

    rows = [
        {"case": "homogeneous", "grid": "840x630", "impl": "native", "mlups": 6000.0},
        {"case": "homogeneous", "grid": "840x630", "impl": "numba-1thread", "mlups": 4000.0},
        {"case": "homogeneous", "grid": "840x630 rz", "impl": "native", "mlups": 3000.0},
        {"case": "homogeneous", "grid": "840x630 rz", "impl": "numba-1thread", "mlups": 3000.0},
        {"case": "full", "grid": "840x630 rz", "impl": "native", "mlups": 900.0},
    ]
    got = {(r["ratio"], r["grid"]): r["value"] for r in bench._ratios(rows)}
    assert got == {
        ("native/numba-1thread", "840x630"): 1.5,
        ("native/numba-1thread", "840x630 rz"): 1.0,
        ("full/homogeneous (native)", "840x630 rz"): 0.3,
    }
    rz = [c for c in bench.CPU_CASES if c.kind == "rz"]
    assert {c.name for c in rz} == {"homogeneous", "full"} and all(c.grid == "840x630 rz" for c in rz)
    for c in rz:
        g, medium, src, sens, edges = bench.scene(c)
        assert g.kind == "rz"
        assert why_not(Stepper.build(g, medium, src, sens, edges)) is None
