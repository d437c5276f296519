"""Design parameters (differentiable) and their limits (static), with the reparameterisation that
keeps every shape physical during an optimisation.

A design is an equinox module of scalar arrays in SI units (`HornParams`, `ReflectorParams`);
its limits (`HornLimits`, `ReflectorLimits`) are static floats. `limits.check(params)` raises a
ValueError naming the parameter for a bad explicit input; `limits.unpack(u)` maps any real vector
to an admissible design (sigmoids / tanh), and `limits.pack(params)` is its inverse, so an
unconstrained optimiser can never produce a self-intersecting or too-thin shape:

- horn: throat in [throat_min, throat_max], mouth in [throat, mouth_max] (mouth >= throat),
  profile monotone for every flare (see `geometry.flare_profile`), walls never cross (their inner
  faces are at least the throat apart), wall thickness in [wall_min, wall_max];
- reflector: focal length in [focal_min, focal_max], aperture in [aperture_min, aperture_max],
  wall thickness in [wall_min, wall_max]; `focal_min` keeps the mirror behind the transducer.
"""

from __future__ import annotations

import math

import equinox as eqx
import jax
import jax.numpy as jnp

from ..lattice.geometry import HornWalls, ParabolicMirror
from ..transforms import logit

_EDGE = 1e-6  # pack() keeps sigmoids this far inside (0, 1): a design exactly at a limit has a finite u


def _logit(p: float) -> float:
    """`logit` of `p` clipped _EDGE inside (0, 1): a design exactly at a limit packs finitely."""
    return logit(min(max(p, _EDGE), 1 - _EDGE))


def _frac(v: float, lo: float, hi: float) -> float:
    return 0.5 if hi == lo else (v - lo) / (hi - lo)


def _require(ok: bool, msg: str) -> None:
    if not ok:
        raise ValueError(msg)


class HornParams(eqx.Module):
    """A flared horn (metres; `flare` dimensionless, 0 = cone; see `geometry.HornWalls`)."""

    throat_m: jax.Array
    mouth_m: jax.Array
    length_m: jax.Array
    wall_m: jax.Array
    flare: jax.Array

    def __init__(self, throat_m, mouth_m, length_m, wall_m, flare=0.0):
        self.throat_m, self.mouth_m, self.length_m, self.wall_m, self.flare = (
            jnp.asarray(v, float) for v in (throat_m, mouth_m, length_m, wall_m, flare)
        )

    NAMES = ("throat_m", "mouth_m", "length_m", "wall_m", "flare")

    def shape(self, anchor_m) -> HornWalls:
        """The walls with the throat centred on `anchor_m` (the transducer face centre)."""
        return HornWalls(
            jnp.asarray(anchor_m, float), self.throat_m, self.mouth_m, self.length_m, self.wall_m, self.flare
        )

    @property
    def half_angle_deg(self):
        """Mean half-angle of the opening, degrees (the cone's half-angle when flare = 0)."""
        return jnp.degrees(jnp.arctan(0.5 * (self.mouth_m - self.throat_m) / self.length_m))

    def as_dict(self) -> dict:
        return {k: float(getattr(self, k)) for k in self.NAMES}


class ReflectorParams(eqx.Module):
    """A parabolic mirror, focus on the transducer (metres; see `geometry.ParabolicMirror`)."""

    focal_m: jax.Array
    aperture_m: jax.Array
    wall_m: jax.Array

    def __init__(self, focal_m, aperture_m, wall_m):
        self.focal_m, self.aperture_m, self.wall_m = (jnp.asarray(v, float) for v in (focal_m, aperture_m, wall_m))

    NAMES = ("focal_m", "aperture_m", "wall_m")

    def shape(self, anchor_m) -> ParabolicMirror:
        return ParabolicMirror(jnp.asarray(anchor_m, float), self.focal_m, self.aperture_m, self.wall_m)

    def as_dict(self) -> dict:
        return {k: float(getattr(self, k)) for k in self.NAMES}


DesignParams = HornParams | ReflectorParams  # the shapes a design optimises


class HornLimits(eqx.Module):
    """User size limits of a horn (metres) and the smallest throat the transducer allows."""

    throat_min_m: float = eqx.field(static=True)
    throat_max_m: float = eqx.field(static=True)
    mouth_max_m: float = eqx.field(static=True)
    length_min_m: float = eqx.field(static=True)
    length_max_m: float = eqx.field(static=True)
    wall_min_m: float = eqx.field(static=True)
    wall_max_m: float = eqx.field(static=True)
    flare_max: float = eqx.field(static=True, default=4.0)

    def __check_init__(self):
        _require(
            0 < self.throat_min_m <= self.throat_max_m <= self.mouth_max_m,
            f"horn limits need 0 < throat_min_m ({self.throat_min_m}) <= throat_max_m ({self.throat_max_m}) "
            f"<= mouth_max_m ({self.mouth_max_m})",
        )
        _require(
            0 < self.length_min_m <= self.length_max_m,
            f"horn limits need 0 < length_min_m ({self.length_min_m}) <= length_max_m ({self.length_max_m})",
        )
        _require(
            0 < self.wall_min_m <= self.wall_max_m,
            f"horn limits need 0 < wall_min_m ({self.wall_min_m}) <= wall_max_m ({self.wall_max_m})",
        )
        _require(self.flare_max >= 0, f"flare_max = {self.flare_max} must be >= 0")

    def check(self, p: HornParams) -> HornParams:
        """Raise ValueError naming the first parameter outside its limits; return `p`."""
        v = p.as_dict()
        tol = 1e-12
        _require(all(math.isfinite(x) for x in v.values()), f"horn parameters must be finite, got {v}")
        _require(
            self.throat_min_m - tol <= v["throat_m"] <= self.throat_max_m + tol,
            f"throat_m = {v['throat_m']:.6g} m outside [{self.throat_min_m:.6g}, {self.throat_max_m:.6g}] m "
            "(the throat must clear the transducer face)",
        )
        _require(
            v["mouth_m"] >= v["throat_m"] - tol,
            f"mouth_m = {v['mouth_m']:.6g} m is narrower than throat_m = {v['throat_m']:.6g} m: "
            "the horn must open (mouth >= throat)",
        )
        _require(
            v["mouth_m"] <= self.mouth_max_m + tol,
            f"mouth_m = {v['mouth_m']:.6g} m exceeds mouth_max_m = {self.mouth_max_m:.6g} m",
        )
        _require(
            self.length_min_m - tol <= v["length_m"] <= self.length_max_m + tol,
            f"length_m = {v['length_m']:.6g} m outside [{self.length_min_m:.6g}, {self.length_max_m:.6g}] m",
        )
        _require(
            self.wall_min_m - tol <= v["wall_m"] <= self.wall_max_m + tol,
            f"wall_m = {v['wall_m']:.6g} m outside [{self.wall_min_m:.6g}, {self.wall_max_m:.6g}] m "
            "(minimum wall thickness)",
        )
        _require(
            abs(v["flare"]) <= self.flare_max + tol,
            f"|flare| = {abs(v['flare']):.6g} exceeds flare_max = {self.flare_max}",
        )
        return p

    def unpack(self, u) -> HornParams:
        """Any real 5-vector -> an admissible horn (mouth >= throat by construction)."""
        s = jax.nn.sigmoid
        throat = self.throat_min_m + (self.throat_max_m - self.throat_min_m) * s(u[0])
        mouth = throat + (self.mouth_max_m - throat) * s(u[1])
        length = self.length_min_m + (self.length_max_m - self.length_min_m) * s(u[2])
        wall = self.wall_min_m + (self.wall_max_m - self.wall_min_m) * s(u[3])
        flare = self.flare_max * jnp.tanh(u[4])
        return HornParams(throat, mouth, length, wall, flare)

    def pack(self, p: HornParams):
        """Inverse of `unpack` (after `check`)."""
        v = self.check(p).as_dict()
        f = v["flare"] / self.flare_max if self.flare_max > 0 else 0.0
        f = min(max(f, -1 + _EDGE), 1 - _EDGE)
        return jnp.array(
            [
                _logit(_frac(v["throat_m"], self.throat_min_m, self.throat_max_m)),
                _logit(_frac(v["mouth_m"], v["throat_m"], self.mouth_max_m)),
                _logit(_frac(v["length_m"], self.length_min_m, self.length_max_m)),
                _logit(_frac(v["wall_m"], self.wall_min_m, self.wall_max_m)),
                math.atanh(f),
            ]
        )


class ReflectorLimits(eqx.Module):
    """User size limits of a parabolic reflector (metres)."""

    focal_min_m: float = eqx.field(static=True)
    focal_max_m: float = eqx.field(static=True)
    aperture_min_m: float = eqx.field(static=True)
    aperture_max_m: float = eqx.field(static=True)
    wall_min_m: float = eqx.field(static=True)
    wall_max_m: float = eqx.field(static=True)

    def __check_init__(self):
        _require(
            0 < self.focal_min_m <= self.focal_max_m,
            f"reflector limits need 0 < focal_min_m ({self.focal_min_m}) <= focal_max_m ({self.focal_max_m})",
        )
        _require(
            0 < self.aperture_min_m <= self.aperture_max_m,
            f"reflector limits need 0 < aperture_min_m ({self.aperture_min_m}) <= aperture_max_m ({self.aperture_max_m})",
        )
        _require(
            0 < self.wall_min_m <= self.wall_max_m,
            f"reflector limits need 0 < wall_min_m ({self.wall_min_m}) <= wall_max_m ({self.wall_max_m})",
        )

    def check(self, p: ReflectorParams) -> ReflectorParams:
        v = p.as_dict()
        tol = 1e-12
        _require(all(math.isfinite(x) for x in v.values()), f"reflector parameters must be finite, got {v}")
        _require(
            self.focal_min_m - tol <= v["focal_m"] <= self.focal_max_m + tol,
            f"focal_m = {v['focal_m']:.6g} m outside [{self.focal_min_m:.6g}, {self.focal_max_m:.6g}] m "
            "(a shorter focal length puts the mirror through the transducer)",
        )
        _require(
            self.aperture_min_m - tol <= v["aperture_m"] <= self.aperture_max_m + tol,
            f"aperture_m = {v['aperture_m']:.6g} m outside [{self.aperture_min_m:.6g}, {self.aperture_max_m:.6g}] m",
        )
        _require(
            self.wall_min_m - tol <= v["wall_m"] <= self.wall_max_m + tol,
            f"wall_m = {v['wall_m']:.6g} m outside [{self.wall_min_m:.6g}, {self.wall_max_m:.6g}] m "
            "(minimum wall thickness)",
        )
        return p

    def unpack(self, u) -> ReflectorParams:
        s = jax.nn.sigmoid
        return ReflectorParams(
            self.focal_min_m + (self.focal_max_m - self.focal_min_m) * s(u[0]),
            self.aperture_min_m + (self.aperture_max_m - self.aperture_min_m) * s(u[1]),
            self.wall_min_m + (self.wall_max_m - self.wall_min_m) * s(u[2]),
        )

    def pack(self, p: ReflectorParams):
        v = self.check(p).as_dict()
        return jnp.array(
            [
                _logit(_frac(v["focal_m"], self.focal_min_m, self.focal_max_m)),
                _logit(_frac(v["aperture_m"], self.aperture_min_m, self.aperture_max_m)),
                _logit(_frac(v["wall_m"], self.wall_min_m, self.wall_max_m)),
            ]
        )
