"""Physically parametrised velocity profiles of a housed diaphragm: one shape parameter each,
between the piston (`fit.housed` "flat"/"recessed"/"opening") and the free per-ring profile
("profile").

An open-type 40 kHz can is a bimorph driving a small conical resonator behind a front mesh: its
radiating surface is not flat and its velocity not uniform. Two one-parameter families describe
that, each reducing to the flat piston at its parameter's zero:

- "cone": the radiating surface's axial position varies linearly with radius, depth `h` from the
  centre to the rim (|h| <= the can's length). On the flat face's lattice it enters as a phase:
  ring j lags the centre by h s_j / c (s = r / a), the wave's travel from the cone's surface to
  the plane of its rim along the axis (the near-axis, shallow-cone approximation; the face stays
  in its plane). The far-field lobe |F| of such a baffled aperture does not change when h changes
  sign (F(-h) is conj F(h): the Rayleigh kernel J0 is real), so a lobe cannot tell apex forward
  from apex back; h is fitted signed and reported as fitted.
- "bending": the velocity falls with radius as a plate's first axisymmetric bending mode to second
  order, w(s) = 1 - q s^2: q = 0 the piston, q = 1 a rim at rest (clamped or supported edge),
  q > 1 a nodal circle at s = 1 / sqrt(q) and the rim in antiphase. q is bounded to
  (`BEND_MIN`, `BEND_MAX`) = (-1, 3): a rim moving at most twice the centre's velocity, in phase
  (q = -1) or in antiphase (q = 3, the nodal circle at 0.58 a; a free-edge plate's first
  axisymmetric mode has it at 0.68 a, q ~ 2.2). Beyond that the "profile" is a ring radiator,
  the free profile's freedom, not a plate's mode.

The profiles are evaluated at each ring's area centroid inside the diaphragm (`ring_centroid_s`):
the lattice's ring source is piecewise constant, and the centroid makes its ring-area integral of
a smooth profile exact to second order in the ring width.
"""

from __future__ import annotations

import math

import jax
import jax.numpy as jnp


def ring_centroid_s(radius_cells, n_rings: int, dtype=float):
    """s = r_c / a of each ring j (radii [j, j + 1] cells) at the area centroid of its part inside
    the radius a (`radius_cells`, traced; differentiable): r_c = 2/3 (hi^3 - lo^3) / (hi^2 - lo^2),
    lo = j, hi = min(j + 1, a). A ring wholly outside the radius gets s = 1 (it carries no area)."""
    j = jnp.arange(n_rings, dtype=dtype)
    hi = jnp.where(j + 1 < radius_cells, j + 1, radius_cells)
    inside = hi > j + 1e-9
    hi_s = jnp.where(inside, hi, j + 1)  # a safe value where the ring is empty
    rc = (2.0 / 3.0) * (hi_s**3 - j**3) / (hi_s**2 - j**2)
    return jnp.where(inside, rc / radius_cells, 1.0)


def cone_lags_s(s, cone_m, c_m_s: float):
    """Per-ring lags (s) of a cone of depth `cone_m` (rim relative to centre): h s / c."""
    return cone_m * s / c_m_s


BEND_MIN, BEND_MAX = -1.0, 3.0
"""Bounds of the bending profile's q (see the module docstring)."""


def bend_from_raw(raw):
    """q = BEND_MIN + (BEND_MAX - BEND_MIN) sigmoid(raw) (raw 0: q = 1, the rim at rest)."""
    return BEND_MIN + (BEND_MAX - BEND_MIN) * jax.nn.sigmoid(raw)


def bend_to_raw(q: float) -> float:
    """The raw parameter of q (inside the bounds: refused otherwise)."""
    if not BEND_MIN < q < BEND_MAX:
        raise ValueError(f"bend = {q} must be inside ({BEND_MIN:g}, {BEND_MAX:g}): the rim at most twice the centre")
    f = (q - BEND_MIN) / (BEND_MAX - BEND_MIN)
    return math.log(f / (1 - f))


def bending_weights(s, bend):
    """Per-ring velocity weights of the bending profile 1 - q s^2 (`bend` = q)."""
    return 1.0 - bend * s * s
