"""Scalar parameter maps shared by the fits and designs (pure Python, no JAX: layer 0).

A bounded physical quantity (an active diameter as a fraction of the largest, a rim width, a
design dimension between its limits) is optimised as an unbounded raw number u with
``fraction = sigmoid(u)``; `logit` gives the raw start value of a fraction. Inside traced code
the forward map is `jax.nn.sigmoid`; these are the host-side (float) versions.
"""

from __future__ import annotations

import math

__all__ = ["logit", "sigmoid"]


def logit(fraction: float) -> float:
    """The raw value u with ``sigmoid(u) = fraction``: ``log(fraction / (1 - fraction))``.

    `fraction` must lie strictly inside (0, 1) (clip it first where a limit itself is allowed:
    a fraction of exactly 0 or 1 has no finite raw value)."""
    f = float(fraction)
    if not 0.0 < f < 1.0:
        raise ValueError(f"logit({fraction!r}): the fraction must lie strictly between 0 and 1; clip it first")
    return math.log(f / (1.0 - f))


def sigmoid(u: float) -> float:
    """The fraction ``1 / (1 + exp(-u))`` of a raw value `u` (the inverse of `logit`); no
    overflow for large |u|."""
    u = float(u)
    if u >= 0:
        return 1.0 / (1.0 + math.exp(-u))
    e = math.exp(u)
    return e / (1.0 + e)
