"""Native CPU kernels for the time loop (XLA FFI custom calls written in C++).

XLA's CPU loop for the 5-point stencil runs at ~0.4x the speed of a vectorised numba loop and
on one core. These kernels advance a chunk of steps per call with temporal blocking and a
pipeline of threads (all cores), for the leapfrog (homogeneous, conservative with coefficient
maps, speed-zero, sponge, soft cells, absorption) with the split-field PML on the layer's cells
only (`difflattice_layered`), with humid air's relaxation (`Medium(air=...)`: two memory
fields), with sources, probes, phasors and field statistics inside the loop; on 3-D grids
`volume.cc` (`volume.py`: the 7-point leapfrog with coefficient arrays, PML layers on their
boxes, the isotropic 19-point stencil on uniform faces; x planes as the pipeline's rows). The JAX
loop stays the reference (tests compare the two), the path for GPUs, and the path of derivatives: a native run's JVP is the JAX
loop's, so `jax.grad` through it gives JAX's gradients; `adjoint="lattice"` runs its forward and
backward passes (the adjoint wave equation) on these kernels instead.

`loop.run(..., backend="auto")` (the default) picks these kernels on a CPU when the scene's
features are supported and a C++ compiler is available (compiled once per machine, see
`build.py`); `backend="native"` insists (and raises with the reason otherwise); `backend="jax"`
never uses them. ``DIFFLATTICE_NATIVE=0`` turns them off; ``DIFFLATTICE_NATIVE_THREADS`` sets the
number of threads (default: the CPUs this process may use).
"""

from __future__ import annotations

from typing import Literal

from .build import load
from .kernels import run_native, unsupported

Backend = Literal["auto", "jax", "native"]
BACKENDS = ("auto", "jax", "native")


def why_not(stepper, state=None, sharding=None) -> str | None:
    """None if `backend="native"` runs this scene, otherwise the reason it does not."""
    reason = unsupported(stepper, state, sharding)
    if reason is None:
        lib = load()
        if isinstance(lib, str):
            reason = lib
    return reason


def dispatch(stepper, n_steps: int, *, state, checkpoint, unroll, sharding, adjoint: str, backend: str):
    """The hook of `loop.run`: a native `Result`, or None to run the JAX loop."""
    if backend not in BACKENDS:
        raise ValueError(f"backend = {backend!r}; allowed: {', '.join(map(repr, BACKENDS))}")
    if backend == "jax":
        return None
    if adjoint == "lattice":
        # the adjoint-wave-equation reverse mode has its own forward and backward passes
        # (solver/adjoint.py), on these kernels where they run the scene; `loop.run` resolves
        # adjoint="auto" before asking here
        return None
    reason = why_not(stepper, state, sharding)
    if reason is not None:
        if backend == "native":
            raise ValueError(f"backend='native' is not available for this run: {reason} (use backend='auto' or 'jax')")
        return None
    return run_native(stepper, n_steps, state=state, checkpoint=checkpoint, unroll=unroll)


__all__ = ["BACKENDS", "Backend", "dispatch", "load", "run_native", "unsupported", "why_not"]
