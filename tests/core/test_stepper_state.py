"""Each stepper carries its own state type: the leapfrog (P, P_prev), and with PML edges the
leapfrog's fields plus the split-field form's on the layer's boxes (`StaggeredState.layers`). The
interior of a PML scene steps the leapfrog, so its fields agree with the leapfrog scene's before a
wave reaches the layer; a start state of the other stepper is refused with a ValueError."""

import jax.numpy as jnp
import numpy as np
import pytest

from difflattice.lattice import Edges
from difflattice.lattice.grid import make_grid
from difflattice.lattice.medium import Medium
from difflattice.solver import LeapfrogState, Sensors, StaggeredState, State, Stepper, run
from difflattice.solver.sources import PointSources, ToneBurst

N, L, STEPS = 48, 8, 14  # source at the centre: the stencil reaches 1 cell per step, 24 - 14 > L


def _stepper(edges: Edges) -> Stepper:
    grid = make_grid(frequency_hz=50e3, cells_per_wavelength=12, c_max_m_s=343.0, shape=(N, N), dtype="float64")
    src = PointSources(
        cells=np.array([[N // 2, N // 2]]),
        signal=ToneBurst(50e3, 3.0),
        weights=jnp.ones(1, jnp.float64),
        lags_s=jnp.zeros(1, jnp.float64),
    )
    sens = Sensors(probes=np.array([[N // 2 + 3, N // 2]]), p_max=True)
    return Stepper.build(grid, Medium(343.0, 1.2), src, sens, edges)


def test_state_type_per_stepper_and_equal_fields_away_from_the_layer():
    leap = _stepper(Edges.all("rigid", thickness_cells=L))
    stag = _stepper(Edges(thickness_cells=L))
    s0, t0 = leap.init(), stag.init()
    assert isinstance(s0, LeapfrogState) and isinstance(t0, StaggeredState)
    assert isinstance(s0, State) and isinstance(t0, State)
    assert not hasattr(s0, "layers") and len(t0.layers) == 4  # x_lo, x_hi, then y_lo, y_hi between them
    assert all(f.c_r is None and len(f.parts) == 2 for f in t0.layers)  # 2-D, no rz layer
    a = run(leap, STEPS, backend="jax")
    b = run(stag, STEPS, backend="jax")
    assert isinstance(a.final, LeapfrogState) and isinstance(b.final, StaggeredState)
    pa, pb = np.asarray(a.final.pressure), np.asarray(b.final.pressure)
    assert np.abs(pa).max() > 0
    np.testing.assert_array_equal(pa, np.asarray(a.final.p))
    np.testing.assert_array_equal(np.asarray(b.final.pressure), np.asarray(b.final.p))
    # same scheme in exact arithmetic: round-off only (float64, ~STEPS * 1e-16 of the peak)
    scale = np.abs(pa).max()
    np.testing.assert_allclose(pb, pa, rtol=0, atol=1e-12 * scale)
    np.testing.assert_allclose(np.asarray(b.probes), np.asarray(a.probes), rtol=0, atol=1e-12 * scale)
    np.testing.assert_allclose(np.asarray(b.p_max), np.asarray(a.p_max), rtol=0, atol=1e-12 * scale)


def test_other_steppers_state_is_refused():
    leap = _stepper(Edges.all("rigid", thickness_cells=L))
    stag = _stepper(Edges(thickness_cells=L))
    with pytest.raises(ValueError, match="carries a StaggeredState, got a LeapfrogState"):
        stag.step(leap.init())
    with pytest.raises(ValueError, match="carries a LeapfrogState, got a StaggeredState"):
        run(leap, 3, state=stag.init())
