"""`simulate(..., progress=...)`: a host-side callback after each chunk of the run. The callback
sees the chunk ends (`Result.chunk_steps`), increasing, ending at the total; the joined result of
the pieces equals the whole run's bit for bit (the same steps from the same states), on the JAX
loop and on the native kernels, with and without a remainder chunk, checkpointing and snapshots;
progress=None leaves the one compiled program untouched."""

from __future__ import annotations

import jax
import jax.numpy as jnp
import numpy as np
import pytest

from difflattice.lattice import Edges
from difflattice.lattice.grid import make_grid
from difflattice.lattice.medium import Medium
from difflattice.solver import Joiner, Sensors, loop, native, run_pieces, simulate
from difflattice.solver.sources import ToneBurst, line_transducer

SHAPE = (40, 32)
SENS = Sensors(probes=[(26, 16), (30, 9)], phasor_cells=[(24, 20), (29, 14)], p_max=True, p_rms=True)
_NATIVE = not isinstance(native.load(), str)


def _scene(edges: Edges):
    g = make_grid(frequency_hz=50e3, cells_per_wavelength=10, c_max_m_s=343.0, shape=SHAPE, dtype="float64")
    src = line_transducer(g, (12 * g.dx_m, 16 * g.dx_m), n_cells=5, signal=ToneBurst(50e3, 2))
    return g, Medium(343.0, 1.2), src


def _equal(a, b) -> None:
    la, lb = jax.tree_util.tree_leaves(a), jax.tree_util.tree_leaves(b)
    assert len(la) == len(lb)
    for x, y in zip(la, lb):
        np.testing.assert_array_equal(np.asarray(x), np.asarray(y))
    assert a.chunk_steps == b.chunk_steps and a.n_steps == b.n_steps


BACKENDS = ["jax"] + (["native"] if _NATIVE else [])


@pytest.mark.parametrize("backend", BACKENDS)
@pytest.mark.parametrize(
    ("edges", "n_steps", "checkpoint", "sensors"),
    [
        (Edges(thickness_cells=6), 150, None, SENS),  # 128 + a 22-step remainder; the PML form
        (Edges.all("rigid"), 97, "sqrt", SENS),  # chunks of 10 (ceil sqrt 97) + 7
        (Edges.all("sponge", thickness_cells=6), 50, None, Sensors(probes=[(26, 16)], snapshot_every=16)),
    ],
)
def test_callback_counts_chunks_and_results_are_bitwise_equal(backend, edges, n_steps, checkpoint, sensors):
    g, med, src = _scene(edges)
    kw = dict(n_steps=n_steps, edges=edges, checkpoint=checkpoint, backend=backend)
    plain = simulate(g, med, src, sensors, **kw)
    seen: list[tuple[int, int]] = []
    reported = simulate(g, med, src, sensors, progress=lambda done, total: seen.append((done, total)), **kw)
    _equal(plain, reported)
    done = [d for d, _ in seen]
    assert all(t == n_steps for _, t in seen)
    assert done == sorted(set(done)) and done[-1] == n_steps
    assert tuple(done) == plain.chunk_steps  # one report per chunk


def test_progress_none_compiles_the_one_program(monkeypatch):
    """Without a callback no piece runs (the whole run is one program, as before the option)."""
    calls = []
    monkeypatch.setattr(loop, "_piece", lambda *a: calls.append(a))
    g, med, src = _scene(Edges.all("rigid"))
    simulate(g, med, src, SENS, n_steps=20, edges=Edges.all("rigid"))
    assert calls == []


def test_pieces_at_any_ends_join_to_the_whole_run():
    """`run_pieces` cut at steps that are not chunk ends: the joined probes, phasors and field
    statistics are the whole run's bit for bit (the same steps from the same states; only the
    chunk ends, and so the per-chunk peaks, are the cuts')."""
    edges = Edges.all("rigid")
    g, med, src = _scene(edges)
    whole = simulate(g, med, src, SENS, n_steps=90, edges=edges, backend="jax")
    from difflattice.solver import Stepper

    joiner = Joiner()
    for piece in run_pieces(Stepper.build(g, med, src, SENS, edges), [7, 40, 90], backend="jax"):
        joiner.add(piece)
    joined = joiner.result()
    assert joined.n_steps == 90 and joined.chunk_steps == (7, 40, 90)
    for name in ("probes", "phasors", "p_max", "p_rms"):
        np.testing.assert_allclose(
            np.asarray(getattr(joined, name)), np.asarray(getattr(whole, name)), rtol=1e-12, atol=1e-15
        )


def test_progress_refuses_traced_calls_and_the_lattice_adjoint():
    edges = Edges.all("rigid")
    g, med, src = _scene(edges)
    with pytest.raises(ValueError, match="adjoint='lattice'"):
        simulate(g, med, src, SENS, n_steps=10, edges=edges, adjoint="lattice", progress=lambda d, t: None)

    def f(c):
        return simulate(g, Medium(c, 1.2), src, SENS, n_steps=10, edges=edges, progress=lambda d, t: None).probes.sum()

    with pytest.raises(ValueError, match="call it eagerly"):
        jax.jit(f)(jnp.asarray(343.0))
    with pytest.raises(ValueError, match="ends must increase"):
        from difflattice.solver import Stepper

        list(run_pieces(Stepper.build(g, med, src, SENS, edges), [5, 5]))
