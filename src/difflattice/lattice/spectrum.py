"""The measured spectral radius of a lattice's operator, for stability limits no formula bounds:
the 3-D isotropic stencil next to rigid obstacles (its flux filter loses the checkerboard's
reduction next to features one cell thin; posts, boxes, walls and steps stay within the
whole-space bound, `tests/core/test_3d_isotropic.py`), and the 3-D wide stencil next to any
obstacle or density contrast (`tests/core/test_wide_3d.py`). `Stepper.build` calls `check_spectrum`.
"""

from __future__ import annotations

import math

import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np

from .coefficients import Lattice
from .operators import operator

MARGIN = 1.01
"""The power iteration's estimate is a lower bound: refuse above 4 / MARGIN."""


def spectral_radius(lat: Lattice, shape: tuple[int, ...], iters: int = 100, seed: int = 0) -> float:
    """Estimate of rho(-D), D the scene's operator (`operators.operator`, lattice units), by
    power iteration from a random start: a lower bound that converges to rho, fast where a mode
    localised at an obstacle stands clear of the bulk (the ratio of the top two eigenvalues). The
    leapfrog is stable iff rho(-D) <= 4."""
    v0 = np.random.default_rng(seed).standard_normal(shape)
    dtype = jnp.result_type(lat.K)

    def op(lat, v):  # soft cells (keep = 0) hold zero: the step's operator is the one compressed to the rest
        return operator(lat, v) if lat.keep is None else lat.keep * operator(lat, lat.keep * v)

    def body(lat, v):  # the next iterate and |D v|
        w = -op(lat, v)
        norm = jnp.sqrt(jnp.sum(w * w))
        return w / norm, norm

    # One iteration per call, the lattice an argument (its arrays are not folded into the program),
    # each waited for, and rho read from the iteration's own norm: measured at 6 M cells (wide
    # stencil), XLA's loop of the whole iteration held ~200 bytes per cell of temporaries, calls left
    # to run ahead queued an output buffer each, and a separate |D v| program fused the reduction
    # into the operator at +1.1 GiB and 10 s of compilation; like this the check adds ~0.3 GiB at
    # build time, the peak of a 3-D scene's memory.
    step = eqx.filter_jit(body)
    v = jnp.asarray(v0 / np.linalg.norm(v0), dtype)
    del v0
    norm = jnp.asarray(0.0)
    for _ in range(iters + 1):  # the last call's norm is |D v| of the iters-th iterate
        v, norm = jax.block_until_ready(step(lat, v))
    return float(norm)


def needs_check(lat: Lattice, ndim: int) -> bool:
    """Whether `lat` claims the 3-D isotropic or wide limit next to obstacles (face conductance
    arrays: rigid and soft obstacles, cut cells, density contrasts for the wide stencil)."""
    claims = ndim == 3 and lat.stencil in ("isotropic", "wide") and lat.bx is not None and lat.uniform_faces
    # a lattice that does not claim it (or whose maps are traced) is held to a formula's bound at build
    return claims and not isinstance(lat.bx, jax.core.Tracer)


def check_spectrum(lat: Lattice, shape: tuple[int, ...]) -> None:
    """Refuse a lattice whose measured spectral radius breaks the leapfrog's bound, naming the fix."""
    if not needs_check(lat, len(shape)):
        return
    rho = spectral_radius(lat, shape)
    if rho > 4.0 / MARGIN:
        c = float(jnp.max(lat.c))
        raise ValueError(
            f"the 3-D {lat.stencil} stencil next to these obstacles is unstable at this courant: the operator's "
            f"measured spectral radius is {rho:.4f} > 4 / {MARGIN} (features one cell thin lose the stencil's "
            f"reduction of the checkerboard): lower the grid courant (to about {math.sqrt(4.0 / MARGIN / rho) * c:.3f} "
            "cells/step), thicken the obstacles, or use stencil='standard'"
        )
