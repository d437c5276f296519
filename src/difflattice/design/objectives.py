"""Differentiable beam measures from a far-field pattern, and weighted design goals.

The pattern is the complex pressure at one range on a uniform, sorted set of angles that
contains 0 deg (the axis); levels are in dB re the on-axis level. All measures are
differentiable almost everywhere in the pattern (the indices they pick, e.g. which two samples
bracket the -6 dB crossing, are piecewise constant; the values between are interpolated):

- `on_axis_db`: 20 log10 |p(0)| / |p_ref(0)| (gain over a reference, e.g. the bare transducer);
- `beam_width_deg`: full width between the -drop dB crossings either side of the axis, each
  linearly interpolated in dB between the bracketing samples (the usual measured beam width);
- `sidelobe_db`: highest level beyond the first minimum outside each crossing (hard max), and
  its soft maximum `tau log sum exp(L / tau)` (an upper bound, within tau ln(n) dB);
- `directivity_db`: 10 log10(|p(0)|^2 / mean |p|^2) over the field of view;
- `sector_fraction`: share of the radiated power (sum |p|^2 over all angles) inside |theta| <= sector.
"""

from __future__ import annotations

import equinox as eqx
import jax.numpy as jnp
import numpy as np
from jaxtyping import Array, Float


def _crossing(levels_db, step_deg: float, drop_db: float):
    """Distance (deg) from index 0 to the first -drop_db crossing along `levels_db` (0 dB at index 0),
    and the index of the first sample below; the whole span if it never drops."""
    below = levels_db < -drop_db
    any_below = jnp.any(below)
    k = jnp.where(any_below, jnp.argmax(below), levels_db.shape[0] - 1)
    k = jnp.maximum(k, 1)
    a, b = levels_db[k - 1], levels_db[k]
    t = jnp.where(any_below, (a + drop_db) / jnp.where(a - b > 0, a - b, 1.0), 1.0)
    return (k - 1 + t) * step_deg, k


def _first_minimum(levels_db, k):
    """Index of the first local minimum at or after index k (the end if none)."""
    n = levels_db.shape[0]
    rising = jnp.concatenate([levels_db[1:] > levels_db[:-1], jnp.array([True])])
    mask = rising & (jnp.arange(n) >= k)
    return jnp.argmax(mask)


def pattern_metrics(
    pattern,
    angles_deg,
    *,
    reference_on_axis=None,
    drop_db: float = 6.0,
    field_of_view_deg: float = 90.0,
    sector_deg: float = 10.0,
    soft_tau_db: float = 1.0,
) -> dict:
    """Beam measures of a complex far-field `pattern` on `angles_deg` (see the module docstring)."""
    a = np.asarray(angles_deg, dtype=float)
    step = float(a[1] - a[0])
    if not np.allclose(np.diff(a), step):
        raise ValueError("pattern_metrics needs uniformly spaced, increasing angles")
    i0 = int(np.argmin(np.abs(a)))
    if abs(a[i0]) > 1e-9:
        raise ValueError("pattern_metrics needs the axis (0 deg) among the angles")
    p2 = jnp.abs(pattern) ** 2
    on = p2[i0]
    level = 10 * jnp.log10(jnp.maximum(p2 / on, 1e-30))
    fov = np.abs(a) <= field_of_view_deg + 1e-9
    right = level[i0:][fov[i0:]]
    left = level[: i0 + 1][::-1][fov[: i0 + 1][::-1]]
    w_r, k_r = _crossing(right, step, drop_db)
    w_l, k_l = _crossing(left, step, drop_db)
    out = {"beam_width_deg": w_r + w_l}
    lobes, masks = [], []
    for side, k in ((right, k_r), (left, k_l)):
        m = jnp.arange(side.shape[0]) > _first_minimum(side, k)
        lobes.append(side)
        masks.append(m)
    lv, mk = jnp.concatenate(lobes), jnp.concatenate(masks)
    out["sidelobe_db"] = jnp.max(jnp.where(mk, lv, -300.0))
    z = jnp.where(mk, lv / soft_tau_db, -300.0 / soft_tau_db)  # a finite fill keeps gradients finite
    zmax = jnp.max(z)
    out["sidelobe_soft_db"] = soft_tau_db * (zmax + jnp.log(jnp.sum(jnp.exp(z - zmax))))
    out["directivity_db"] = 10 * jnp.log10(on / jnp.mean(p2[fov]))
    sector = np.abs(a) <= sector_deg + 1e-9
    out["sector_fraction"] = jnp.sum(p2[sector]) / jnp.sum(p2)
    ref = on if reference_on_axis is None else jnp.asarray(reference_on_axis) ** 2
    out["on_axis_db"] = 10 * jnp.log10(on / ref)
    return out


class Goal(eqx.Module):
    """A weighted design goal (all static): loss = - gain_weight * on_axis_db
    + width_weight * ((beam_width - width_target) / width_scale)^2 + sidelobe_weight * soft SLL
    - directivity_weight * DI - sector_weight * 10 log10(sector fraction). Lower is better."""

    gain_weight: float = eqx.field(static=True, default=0.0)
    width_target_deg: float | None = eqx.field(static=True, default=None)
    width_weight: float = eqx.field(static=True, default=0.0)
    width_scale_deg: float = eqx.field(static=True, default=1.0)
    sidelobe_weight: float = eqx.field(static=True, default=0.0)
    directivity_weight: float = eqx.field(static=True, default=0.0)
    sector_weight: float = eqx.field(static=True, default=0.0)

    def __check_init__(self):
        if self.width_weight and self.width_target_deg is None:
            raise ValueError("Goal: width_weight > 0 needs width_target_deg")
        if not any(
            (self.gain_weight, self.width_weight, self.sidelobe_weight, self.directivity_weight, self.sector_weight)
        ):
            raise ValueError("Goal: give at least one non-zero weight")

    def loss(self, m: dict) -> Float[Array, ""] | float:
        total: Float[Array, ""] | float = 0.0
        if self.gain_weight:
            total = total - self.gain_weight * m["on_axis_db"]
        if self.width_weight:
            total = (
                total + self.width_weight * ((m["beam_width_deg"] - self.width_target_deg) / self.width_scale_deg) ** 2
            )
        if self.sidelobe_weight:
            total = total + self.sidelobe_weight * m["sidelobe_soft_db"]
        if self.directivity_weight:
            total = total - self.directivity_weight * m["directivity_db"]
        if self.sector_weight:
            total = total - self.sector_weight * 10 * jnp.log10(m["sector_fraction"])
        return total

    def describe(self) -> str:
        parts = []
        if self.gain_weight:
            parts.append(f"{self.gain_weight:g} x on-axis gain (max)")
        if self.width_weight:
            parts.append(
                f"{self.width_weight:g} x ((-6 dB width - {self.width_target_deg:g} deg) / {self.width_scale_deg:g} deg)^2 (min)"
            )
        if self.sidelobe_weight:
            parts.append(f"{self.sidelobe_weight:g} x soft side-lobe level (min)")
        if self.directivity_weight:
            parts.append(f"{self.directivity_weight:g} x directivity index (max)")
        if self.sector_weight:
            parts.append(f"{self.sector_weight:g} x sector power fraction in dB (max)")
        return "; ".join(parts)
