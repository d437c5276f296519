"""The lattice-kind abstraction holds: a fourth kind, a rank-1 tube, defined here by the recipe
of docs/architecture.md ("A new lattice kind": one `LatticeKind` subclass with its name, rank,
axes and stability limit) runs through `simulate` with a source and a probe, with nothing in the
package told about it.

Reference (independent of the stepper's code): at courant 1 the 1-D leapfrog
p(n+1, x) = p(n, x+1) + p(n, x-1) - p(n-1, x) is exact (the "magic time step"): a unit value added
at (x0, m) gives p(n, x) = 1 wherever |x - x0| <= n - m and n - m - |x - x0| is even (check:
the comb satisfies the recursion and starts as the impulse). So a probe d cells away reads
sum of v(m) over m <= n - d with n - m - d even, v(m) the source's injected values, exactly, until
a wall's reflection arrives. Tolerance: float64 round-off of ~n additions (1e-12 relative).
"""

import math

import numpy as np
import pytest

from difflattice.lattice import Edges, Grid, Medium
from difflattice.lattice.kinds import LatticeKind
from difflattice.solver import PointSources, Sensors, ToneBurst, simulate


class Tube(LatticeKind):
    """A rank-1 lattice (a narrow tube): cells along x, the three-point Laplacian, rho(-L) < 4 so
    the leapfrog is stable up to c = 1 cell/step."""

    name = "1d"
    label = "1-D"
    noun = "tube"
    ndim = 1
    axis_names = ("x",)
    default_courant = 1.0
    _standard_limit = 1.0
    _standard_formula = "1"


def _run(n_cells=400, x0=100, x1=160, n_steps=150, courant=1.0):
    grid = Grid(
        shape=(n_cells,),
        frequency_hz=40e3,
        cells_per_wavelength=20.0,
        c_max_m_s=343.0,
        courant=courant,
        dtype="float64",
        kind=Tube(),
    )
    src = PointSources(cells=np.array([[x0]]), signal=ToneBurst(40e3, 3), weights=np.ones(1), lags_s=np.zeros(1))
    r = simulate(
        grid, Medium(343.0, 1.2), src, Sensors(probes=np.array([[x1]])), n_steps=n_steps, edges=Edges.all("rigid")
    )
    v = np.array([float(src.injected(m * grid.dt_s, grid.dt_s, None)[0]) for m in range(1, n_steps + 1)])
    return grid, np.asarray(r.probes)[:, 0], v


def test_a_toy_fourth_kind_runs_through_simulate_and_matches_the_exact_discrete_solution():
    grid, probe, v = _run()
    assert grid.kind.stability_limit() == 1.0 and grid.ndim == 1 and grid.cell_of((0.0,)) == (0,)
    d = 60
    want = np.zeros_like(probe)
    for n in range(1, len(probe) + 1):
        m = np.arange(1, n - d + 1)
        m = m[(n - m - d) % 2 == 0]
        want[n - 1] = v[m - 1].sum()
    assert np.max(np.abs(want)) > 0.5  # the burst has arrived in the window compared
    np.testing.assert_allclose(probe, want, rtol=0, atol=1e-12 * np.max(np.abs(want)))


def test_the_toy_kinds_stability_limit_is_enforced_and_its_edges_checked():
    with pytest.raises(ValueError, match="exceeds the 1-D stability limit 1 = 1.000000"):
        _run(courant=1.001)
    grid, _, _ = _run(n_steps=2)
    with pytest.raises(ValueError, match="PML and Mur edges are written for rank-2 and rank-3 grids"):
        simulate(grid, Medium(343.0, 1.2), n_steps=2, edges=Edges())
    assert math.isclose(grid.coordinates_m()[0][1], grid.dx_m)
