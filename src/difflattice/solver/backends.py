"""The backends of the time loop and the one chooser.

A backend runs a `Request` (a stepper, a step count and how to run it) and says, before it
runs, whether it can: `supports(request)` is None, or the reason it cannot. Four backends:

- `JaxLoop` ("jax"): the JAX scan (`scan.run_jax`), the reference; runs everything unsharded.
- `Sharded` ("sharded"): the same scan with the fields split across devices (`sharding=`).
- `Native` ("native"): the C++ kernels on a CPU (`solver.native`: `why_not`, `run_native`).
- `LatticeAdjoint` ("lattice adjoint"): the forward run whose reverse mode is the adjoint wave
  equation (`solver.adjoint`), on the native kernels where they run the scene.

`choose(request, backend)` asks them in order (native, lattice adjoint, sharded, jax) and returns
the first that supports the request with the reasons of those it passed over; `run` (loop.py)
runs it and records both in the `Result` (`backend`, `backend_why_not`). A new backend is a class
with `name`, `supports` and `run`, and one place in `_candidates`.

This module imports the native kernels and the adjoint; `loop` imports it (the solver's imports
form no circle: `scan` <- native, adjoint <- backends <- loop).
"""

from __future__ import annotations

import dataclasses
from dataclasses import dataclass
from typing import Literal, Protocol, runtime_checkable

import equinox as eqx
import jax
import jax.numpy as jnp

from . import adjoint as adj
from . import native
from .scan import Checkpoint, Result, chunking, run_jax
from .stepper import State, Stepper

BackendName = Literal["auto", "jax", "native"]
"""What a user may ask for (`run(..., backend=...)`): "auto" lets the chooser pick."""
BACKEND_CHOICES = ("auto", "jax", "native")


@dataclass(frozen=True)
class Request:
    """One run to make: `run`'s arguments (`adjoint="auto"` is resolved by `choose`)."""

    stepper: Stepper
    n_steps: int
    state: State | None = None
    checkpoint: Checkpoint = None
    unroll: int | None = None
    sharding: jax.sharding.Sharding | None = None
    adjoint: Literal["autodiff", "lattice", "auto"] = "autodiff"


@runtime_checkable
class Backend(Protocol):
    """A way to run a `Request`: `supports` (None, or the reason it cannot) and `run`."""

    name: str

    def supports(self, request: Request) -> str | None: ...

    def run(self, request: Request) -> Result: ...


class JaxLoop:
    """The JAX scan on one device (the reference, and the path on GPUs)."""

    name = "jax"

    def supports(self, request: Request) -> str | None:
        if request.sharding is not None:
            return "a sharding was given (the sharded loop runs it)"
        return None

    def run(self, request: Request) -> Result:
        r = request
        return run_jax(r.stepper, r.n_steps, state=r.state, checkpoint=r.checkpoint, unroll=r.unroll)


class Sharded:
    """The JAX scan with the grid-shaped fields split across devices every step."""

    name = "sharded"

    def supports(self, request: Request) -> str | None:
        if request.sharding is None:
            return "no sharding given (sharding=grid_sharding())"
        return None

    def run(self, request: Request) -> Result:
        r = request
        return run_jax(
            r.stepper, r.n_steps, state=r.state, checkpoint=r.checkpoint, unroll=r.unroll, sharding=r.sharding
        )


class Native:
    """The C++ kernels of `solver.native` (CPU); their derivatives are the JAX loop's."""

    name = "native"

    def supports(self, request: Request) -> str | None:
        if request.adjoint == "lattice":
            return "adjoint='lattice' (its own forward pass runs on these kernels where they run the scene)"
        return native.why_not(request.stepper, request.state, request.sharding)

    def run(self, request: Request) -> Result:
        r = request
        return native.run_native(r.stepper, r.n_steps, state=r.state, checkpoint=r.checkpoint, unroll=r.unroll)


class LatticeAdjoint:
    """The forward run whose reverse mode is the adjoint wave equation (`solver.adjoint`); its
    forward and backward passes are native where `on_native` (the chooser decides)."""

    name = "lattice adjoint"

    def __init__(self, on_native: bool = False):
        self.on_native = on_native

    def supports(self, request: Request) -> str | None:
        if request.adjoint != "lattice":
            return "adjoint='autodiff' (JAX's reverse mode of the loop that runs)"
        return self.scene_reason(request)

    @staticmethod
    def scene_reason(request: Request) -> str | None:
        """None if the adjoint wave equation differentiates this run, otherwise why not."""
        reason = adj.supports(request.stepper, request.state)
        if reason is None and request.sharding is not None:
            return "sharding (the adjoint runs on one device)"
        return reason

    def run(self, request: Request) -> Result:
        r = request
        chunk = chunking(r.n_steps, r.stepper.sensors, "sqrt" if r.checkpoint is None else r.checkpoint)
        probes, re, im, p, p_prev, peaks = adj.linear_run(r.stepper, r.n_steps, chunk, self.on_native)
        final = eqx.tree_at(
            lambda s: (s.p, s.p_prev, s.n, s.phasor_re, s.phasor_im),
            r.stepper.init(),
            (p, p_prev, jnp.asarray(r.n_steps, jnp.int32), re, im),
            is_leaf=lambda x: x is None,
        )
        n_chunks, rem = divmod(r.n_steps, chunk)
        steps = [chunk * (i + 1) for i in range(n_chunks)] + ([r.n_steps] if rem else [])
        return Result(
            final=final,
            probes=probes,
            phasors=None if re is None else jax.lax.complex(re, im),
            p_max=None,
            p_rms=None,
            arrival=None,
            snapshots=None,
            peak_history=peaks,
            n_steps=r.n_steps,
            chunk_steps=tuple(steps),
        )


@dataclass(frozen=True)
class Choice:
    """The backend that runs a request (`adjoint` resolved) and, for each one passed over, why."""

    backend: Backend
    why_not: tuple[tuple[str, str], ...]
    request: Request

    def run(self) -> Result:
        """Run the request on the chosen backend; the `Result` says which ran and why not the others."""
        result = self.backend.run(self.request)
        return dataclasses.replace(result, backend=self.backend.name, backend_why_not=self.why_not)


def _candidates(request: Request, backend: str) -> list[Backend]:
    """The backends `backend` allows, in the order the chooser asks them."""
    allow_native = backend != "jax"
    on_native = allow_native and native.why_not(request.stepper, request.state, request.sharding) is None
    out: list[Backend] = [Native()] if allow_native else []
    return out + [LatticeAdjoint(on_native), Sharded(), JaxLoop()]


def choose(request: Request, backend: str = "auto") -> Choice:
    """The first backend (native, lattice adjoint, sharded, jax) that supports `request` under
    `backend` ("auto", "jax": never native, "native": native or the lattice adjoint on the
    native kernels, else a ValueError with the reason); adjoint='lattice' that no backend runs
    is a ValueError naming why; adjoint='auto' is the lattice adjoint where it runs."""
    if backend not in BACKEND_CHOICES:
        raise ValueError(f"backend = {backend!r}; allowed: {', '.join(map(repr, BACKEND_CHOICES))}")
    auto_reason = None
    if request.adjoint == "auto":  # the adjoint wave equation where it supports the run, else JAX's reverse mode
        auto_reason = LatticeAdjoint.scene_reason(request)
        request = dataclasses.replace(request, adjoint="lattice" if auto_reason is None else "autodiff")
    why: list[tuple[str, str]] = []
    if backend == "jax":
        why.append(("native", "backend='jax' was asked for"))
    for b in _candidates(request, backend):
        reason = b.supports(request)
        if reason is None:
            _check_insisted(request, backend, b, why)
            return Choice(b, tuple(why), request)
        if auto_reason is not None and isinstance(b, LatticeAdjoint):
            reason = f"{auto_reason} (adjoint='auto' chose JAX's reverse mode)"
        if request.adjoint == "lattice" and isinstance(b, LatticeAdjoint):
            raise ValueError(
                f"adjoint='lattice' does not support {reason}: use adjoint='autodiff' (or 'auto' to choose per scene)"
            )
        why.append((b.name, reason))
    raise AssertionError("the JAX loop or the sharded loop runs every request")  # pragma: no cover


def _check_insisted(request: Request, backend: str, chosen: Backend, why: list[tuple[str, str]]) -> None:
    """backend='native' refuses a run the native kernels do not make (forward or adjoint)."""
    if backend != "native":
        return
    if isinstance(chosen, Native) or (isinstance(chosen, LatticeAdjoint) and chosen.on_native):
        return
    reason = native.why_not(request.stepper, request.state, request.sharding) or dict(why).get("native", "")
    raise ValueError(f"backend='native' is not available for this run: {reason} (use backend='auto' or 'jax')")
