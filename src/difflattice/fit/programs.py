"""How the fit's own small programs are compiled.

A fit's residuals, Jacobians, optimiser steps and bookkeeping are small XLA programs (arrays of
hundreds of elements, matrices of hundreds x hundreds) that each new process compiles once. LLVM's
optimisation passes dominate their compile time and buy little at run time, so they are compiled
at XLA's backend optimisation level 0 (`small_jit`). The lattice runs (the transfers) are large
programs whose run time matters: they keep the default (`jax.jit`), as do the housed fits, whose
residual is a lattice run.

Where JAX's persistent cache is on (the command line), a small program is also kept whole on disk
(`program_cache`): a new process loads the compiled program without tracing or lowering it.
"""

from __future__ import annotations

import functools
from collections.abc import Callable
from types import MappingProxyType
from typing import Any

import equinox as eqx
import jax

from ..solver.program_cache import CachedProgram

__all__ = ["SMALL_PROGRAM_OPTIONS", "small_jit"]

SMALL_PROGRAM_OPTIONS = MappingProxyType({"xla_backend_optimization_level": 0})
"""XLA compiler options of the fit's small programs (see the module docstring)."""


def small_jit(fn: Callable) -> Callable:
    """`equinox.filter_jit` with `SMALL_PROGRAM_OPTIONS` where `fn` is a program of its own.

    Called from inside another traced function (an argument is a tracer), `fn` is traced into
    that program as a plain `filter_jit` call: XLA takes compiler options at the top level only.
    At the top level the program comes from `program_cache` where it can (same results: the same
    function traced on the same arguments and compiled with the same options)."""
    options: dict[str, Any] = {"compiler_options": dict(SMALL_PROGRAM_OPTIONS)}  # passed on to jax.jit
    top = eqx.filter_jit(fn, **options)
    nested = eqx.filter_jit(fn)
    cached = CachedProgram(fn, SMALL_PROGRAM_OPTIONS)

    @functools.wraps(fn)
    def call(*args: Any, **kwargs: Any) -> Any:
        traced = any(isinstance(x, jax.core.Tracer) for x in jax.tree_util.tree_leaves((args, kwargs)))
        if traced:
            return nested(*args, **kwargs)
        out = cached(args, kwargs)
        return top(*args, **kwargs) if out is NotImplemented else out

    return call
