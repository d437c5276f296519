"""The backend protocol and the one chooser (solver/backends.py): each backend says why it cannot
run a request; the chooser picks the first that can (native, lattice adjoint, sharded, jax),
records which ran and why not the others in the `Result`, and keeps `run`'s refusals."""

from __future__ import annotations

import jax
import numpy as np
import pytest

from difflattice.lattice import Edges
from difflattice.lattice.grid import make_grid
from difflattice.lattice.medium import Medium
from difflattice.solver import Sensors, Stepper, grid_sharding, native, run, simulate
from difflattice.solver.backends import Backend, JaxLoop, LatticeAdjoint, Native, Request, Sharded, choose
from difflattice.solver.sources import ToneBurst, line_transducer

_NATIVE = native.load()
HAVE_NATIVE = not isinstance(_NATIVE, str)
SENS = Sensors(probes=[(20, 12)])


def _stepper(edges: Edges) -> Stepper:
    g = make_grid(frequency_hz=50e3, cells_per_wavelength=10, c_max_m_s=343.0, shape=(32, 24), dtype="float64")
    src = line_transducer(g, (10 * g.dx_m, 12 * g.dx_m), n_cells=3, signal=ToneBurst(50e3, 2))
    return Stepper.build(g, Medium(343.0, 1.2), src, SENS, edges)


def test_every_backend_follows_the_protocol():
    for b in (JaxLoop(), Sharded(), Native(), LatticeAdjoint()):
        assert isinstance(b, Backend)
        assert isinstance(b.name, str) and b.name


def test_auto_picks_the_first_that_runs_and_says_why_not_the_others():
    st = _stepper(Edges.all("rigid"))
    choice = choose(Request(st, 40), "auto")
    why = dict(choice.why_not)
    if HAVE_NATIVE:
        assert choice.backend.name == "native" and why == {}
    else:
        assert choice.backend.name == "jax"
        assert why["native"] == _NATIVE  # the library's reason (no compiler, turned off, ...)
        assert "adjoint='autodiff'" in why["lattice adjoint"] and "no sharding" in why["sharded"]
    res = run(st, 40)
    assert res.backend == choice.backend.name and res.backend_why_not == choice.why_not


def test_jax_backend_and_the_reasons_in_the_result():
    st = _stepper(Edges(thickness_cells=6))
    res = jax.jit(lambda s: run(s, 30, backend="jax"))(st)
    assert res.backend == "jax"
    assert dict(res.backend_why_not)["native"] == "backend='jax' was asked for"


def test_results_are_the_backends_own():
    """The chooser adds only the two static fields: the arrays are the backend's run's."""
    st = _stepper(Edges.all("rigid"))
    direct = JaxLoop().run(Request(st, 30))
    chosen = run(st, 30, backend="jax")
    for a, b in zip(jax.tree_util.tree_leaves(direct), jax.tree_util.tree_leaves(chosen)):
        np.testing.assert_array_equal(np.asarray(a), np.asarray(b))


def test_lattice_adjoint_is_chosen_for_auto_where_it_runs():
    st = _stepper(Edges.all("rigid"))
    res = run(st, 30, adjoint="auto", backend="jax")
    assert res.backend == "lattice adjoint"
    assert dict(res.backend_why_not)["native"] == "backend='jax' was asked for"
    # a PML edge: the lattice adjoint says why not, and insisting on it is refused with that reason
    pml = _stepper(Edges(thickness_cells=6))
    assert "PML" in dict(run(pml, 30, adjoint="auto", backend="jax").backend_why_not)["lattice adjoint"]
    with pytest.raises(ValueError, match="adjoint='lattice' does not support a PML edge"):
        run(pml, 30, adjoint="lattice")


def test_sharded_runs_a_sharding_and_native_says_why_not():
    st = _stepper(Edges.all("rigid"))
    sharding = grid_sharding(jax.devices()[:1])
    res = simulate(st.grid, Medium(343.0, 1.2), (), SENS, n_steps=10, edges=Edges.all("rigid"), sharding=sharding)
    assert res.backend == "sharded"
    why = dict(res.backend_why_not)
    if HAVE_NATIVE:
        assert why["native"] == "a sharded run (the native kernels run on one host)"


def test_refusals_name_the_reason():
    mur = _stepper(Edges.all("mur"))
    with pytest.raises(ValueError, match="backend='native' is not available for this run: .*Mur edges"):
        run(mur, 10, backend="native")
    with pytest.raises(ValueError, match="allowed: 'auto', 'jax', 'native'"):
        run(mur, 10, backend="gpu")  # type: ignore[arg-type]
