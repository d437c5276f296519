"""Transducer models for fitting: parameterisations of weights, lags and active diameter.

Every fitted quantity is an unconstrained array; positivity and ranges come from
reparameterisation (optimistix has no bounds):

- weight w = exp(u) > 0, with the centre cell's weight pinned to 1 and no constant term in a
  smooth profile (the overall scale is the fitted gain, so it must not be a parameter too);
- lag tau = (T/2) tanh(v) in (-T/2, T/2), T the drive period (at one frequency a lag is only
  defined modulo the period); the centre cell's lag is 0 (a common lag is the phase offset);
- active diameter D = D_max sigmoid(d), with a soft aperture window per cell
  sigmoid((D/2 - |y_k|) / s), s = wavelength/20 (a physical, resolution-independent edge).

Parameterisations of a profile across the face ("weights" and "lags" each):
"uniform" (no parameters), "free" (one per cell), "symmetric" (one per mirror pair), "smooth"
(`n_basis` Chebyshev coefficients; even polynomials only when `symmetric`).
"""

from __future__ import annotations

import dataclasses
import math
from collections.abc import Callable
from dataclasses import dataclass
from typing import ClassVar, Literal

import jax
import jax.numpy as jnp
import numpy as np
from jaxtyping import Array, Float

from ..transforms import logit
from .family import FamilyParams, ModelFamily
from .programs import small_jit


def device_array(x) -> Array:
    """`x` (NumPy or Python values) as a strongly typed JAX array, by a plain transfer. Host
    values through `jnp.asarray` (or `jnp.zeros` and the like, outside a program) each run a
    one-operation XLA program, compiled anew for every shape in a fresh process (~10 ms each,
    ~20 per fit); a JAX array or tracer is returned as it is."""
    return x if isinstance(x, jax.Array) else jax.device_put(np.asarray(x))


Profile = Literal["uniform", "free", "symmetric", "smooth"]
PROFILES = ("uniform", "free", "symmetric", "smooth")


class LineParams(FamilyParams):
    """Raw (unconstrained) parameters of the line family (`ModelSpec`); None where not fitted.
    Fields in alphabetical (`ravel_pytree`) order."""

    diam: Float[Array, ""] | None = None
    """Active diameter, logit(D / D_max) (D = D_max sigmoid(diam), D_max the line's length);
    None when the diameter is held at `ModelSpec.diameter_m`."""
    gain_db: Float[Array, ""] | None = None
    """Level offset of the lobe, dB (the transfer's units to the data's); None without lobe data."""
    lag: Float[Array, " n_lag"] | None = None
    """Lag profile, artanh(2 tau / T) (tau = (T/2) tanh(.), T the period): Chebyshev coefficients
    without the constant term ("smooth"), or per cell / mirror pair with the centre cell pinned at
    0 ("free", "symmetric"); None for "uniform"."""
    phase0: Float[Array, ""] | None = None
    """Carrier phase offset of the wavefront, rad; None without wavefront data."""
    w: Float[Array, " n_w"] | None = None
    """Log-weight profile (w = exp(.), relative to the centre): coefficients or per-cell values as
    for `lag`; None for "uniform"."""


@dataclass(frozen=True)
class ModelSpec(ModelFamily[LineParams]):
    """The line family: a line of `n_cells` source cells of pitch `dx_m` on the 2-D lattice (static
    description: what is fitted, how)."""

    kind: ClassVar[str] = "line"

    n_cells: int
    dx_m: float
    frequency_hz: float
    weights: Profile = "smooth"
    lags: Profile = "smooth"
    n_basis: int = 4
    symmetric: bool = True
    fit_diameter: bool = True
    diameter_m: float | None = None  # initial active diameter (default: the whole line)

    def __post_init__(self):
        for name in ("weights", "lags"):
            v = getattr(self, name)
            if v not in PROFILES:
                raise ValueError(f"model {name} = {v!r}; allowed: {', '.join(PROFILES)}")
        if self.n_basis < 1:
            raise ValueError(f"n_basis = {self.n_basis} must be >= 1")

    @property
    def y_m(self) -> np.ndarray:
        return (np.arange(self.n_cells) - (self.n_cells - 1) / 2.0) * self.dx_m

    @property
    def d_max_m(self) -> float:
        return self.n_cells * self.dx_m

    @property
    def edge_softness_m(self) -> float:
        """Width scale of the aperture's edge: 1/20 of the wavelength in air at 343 m/s, in metres
        (resolution independent, and wide enough that the cost is smooth in the diameter)."""
        return 343.0 / self.frequency_hz / 20

    @property
    def period_s(self) -> float:
        return 1.0 / self.frequency_hz

    @property
    def reference_cells(self) -> tuple[int, ...]:
        """The cell(s) profiles are referred to (relative weights and lags): the centre cell, or
        the two central cells of an even line."""
        n = self.n_cells
        return (n // 2,) if n % 2 else (n // 2 - 1, n // 2)

    # -- basis ------------------------------------------------------------------------
    def _basis(self, first: int = 0) -> np.ndarray:
        """(n_cells, n_basis) Chebyshev polynomials of the normalised position, skipping the
        first `first` (even, when symmetric) degrees."""
        u = self.y_m / (self.d_max_m / 2)
        step = 2 if self.symmetric else 1
        degs = [step * (i + first) for i in range(self.n_basis)]
        return np.stack([np.cos(d * np.arccos(np.clip(u, -1, 1))) for d in degs], 1)

    def _n_params(self, profile: str, pinned: bool = False) -> int:
        n = {"uniform": 0, "free": self.n_cells, "symmetric": (self.n_cells + 1) // 2, "smooth": self.n_basis}[profile]
        return n - 1 if pinned and profile in ("free", "symmetric") else n

    def _expand(self, profile: str, p, pinned: bool = False):
        """Raw parameters -> per-cell raw values. With `pinned` the centre cell's value is 0 and a
        smooth profile has no constant term: a common lag is the fitted phase offset, a common
        log-weight the fitted gain."""
        if profile == "smooth":
            return jnp.asarray(self._basis(first=1 if pinned else 0)) @ p
        if profile == "free":
            if pinned:
                c = self.n_cells // 2
                p = jnp.concatenate([p[:c], jnp.zeros(1, p.dtype), p[c:]])
            return p
        if profile == "symmetric":
            half = jnp.concatenate([p, jnp.zeros(1, p.dtype)]) if pinned else p
            n = self.n_cells
            return jnp.concatenate([half, half[: n // 2][::-1]]) if n % 2 else jnp.concatenate([half, half[::-1]])
        return None

    # -- parameters -------------------------------------------------------------------
    def init_params(self) -> LineParams:
        """Initial raw parameters: uniform weights 1, no lags, the initial diameter."""
        nw = self._n_params(self.weights, pinned=True)
        nl = self._n_params(self.lags, pinned=True)
        diam = None
        if self.fit_diameter:
            d0 = self.diameter_m or 0.97 * self.d_max_m
            frac = min(max(d0 / self.d_max_m, 1e-3), 1 - 1e-3)
            diam = device_array(logit(frac))
        return LineParams(
            diam=diam,
            gain_db=device_array(0.0),
            lag=device_array(np.zeros(nl)) if nl else None,
            phase0=device_array(0.0),
            w=device_array(np.zeros(nw)) if nw else None,
        )

    def physical(self, params: LineParams) -> dict:
        """Raw parameters -> physical: weights (aperture applied), lags_s, diameter_m, gain_db,
        phase0_rad."""
        w = jnp.ones(self.n_cells)
        if params.w is not None:
            w = jnp.exp(self._expand(self.weights, params.w, pinned=True))
        lag = jnp.zeros(self.n_cells)
        if params.lag is not None:
            lag = 0.5 * self.period_s * jnp.tanh(self._expand(self.lags, params.lag, pinned=True))
        if params.diam is not None:
            diam = self.d_max_m * jax.nn.sigmoid(params.diam)
        else:
            diam = jnp.asarray(self.diameter_m or self.d_max_m)
        window = jax.nn.sigmoid((diam / 2 - jnp.abs(jnp.asarray(self.y_m))) / self.edge_softness_m)
        return {
            "weights": w * window,
            "weights_raw": w,
            "lags_s": lag,
            "diameter_m": diam,
            "gain_db": jnp.asarray(0.0) if params.gain_db is None else params.gain_db,
            "phase0_rad": jnp.asarray(0.0) if params.phase0 is None else params.phase0,
        }

    def amplitudes(self, params: LineParams):
        """Complex cell amplitudes a_k = w_k exp(i omega tau_k) (exp(-i omega t) convention)."""
        ph = self.physical(params)
        return ph["weights"] * jnp.exp(1j * 2 * math.pi * self.frequency_hz * ph["lags_s"])

    # -- structure of the parameterisation (for error budgets, warm starts, labels) ------
    def expansion(self, profile: str) -> np.ndarray:
        """(n_cells, n_params) matrix E of the linear map from a profile's raw parameters to its
        per-cell raw values (log weight, or artanh(2 lag / T)); (n_cells, 0) for "uniform"."""
        n = self._n_params(profile, pinned=True)
        if n == 0:
            return np.zeros((self.n_cells, 0))
        # the matrix of `_expand(profile, ., pinned=True)`, in NumPy (eagerly, a jacfwd of it ran
        # ~20 one-operation XLA programs per fit)
        if profile == "smooth":
            return self._basis(first=1)
        eye = np.eye(n)
        if profile == "free":  # the centre cell pinned at 0
            return np.insert(eye, self.n_cells // 2, 0.0, axis=0)
        half = np.concatenate([eye, np.zeros((1, n))])  # "symmetric": the centre pinned, mirrored
        m = self.n_cells
        return np.concatenate([half, half[: m // 2][::-1]]) if m % 2 else np.concatenate([half, half[::-1]])

    def raw_labels(self, params: LineParams) -> list[str]:
        """Names of the raw parameters in `jax.flatten_util.ravel_pytree(params)` order: smooth
        profile coefficients as `w.T2` (Chebyshev degree), per-cell ones as `w[k]` (free) or
        `w[k|n-1-k]` (symmetric: one value for a mirror pair), `diameter.logit`, `gain_db`,
        `phase0_rad`."""
        out: list[str] = []
        for key in params.names():
            if key in ("w", "lag"):
                profile = self.weights if key == "w" else self.lags
                n = self.n_cells
                if profile == "smooth":
                    step = 2 if self.symmetric else 1
                    out += [f"{key}.T{step * (i + 1)}" for i in range(self.n_basis)]
                elif profile == "free":
                    c = n // 2
                    out += [f"{key}[{k}]" for k in range(n) if k != c]
                else:
                    out += [f"{key}[{k}|{n - 1 - k}]" for k in range(self._n_params(profile, pinned=True))]
            else:
                out.append({"diam": "diameter.logit", "gain_db": "gain_db", "phase0": "phase0_rad"}.get(key, key))
        return out

    def bounds(self) -> dict:
        """Physical bounds the parameterisation imposes, for error budgets: `diameter_mm` in
        (0, line length), `lag_us` in (-T/2, T/2) (a lag is defined modulo the period)."""
        half_us = 0.5 * self.period_s * 1e6
        return {"diameter_mm": (0.0, self.d_max_m * 1e3), "lag_us": (-half_us, half_us)}

    def params_from_profiles(
        self, log_weights, lag_args, diameter_m: float | None, template: FamilyParams
    ) -> LineParams:
        """Raw parameters of this model closest (least squares) to per-cell raw values: `log_weights`
        (log w_k) and `lag_args` (artanh(2 tau_k / T)) at this model's cells, and the active
        `diameter_m`. Offsets (gain, phase0) are those of `template` (e.g. another fit's parameters,
        for a warm start across resolutions or model families; absent there, absent here) and are
        re-set by the fit."""
        out: dict = {}
        for key, profile, v in (("w", self.weights, log_weights), ("lag", self.lags, lag_args)):
            n = self._n_params(profile, pinned=True)
            if n:
                E = self.expansion(profile)
                v = np.asarray(v, float)
                pinned = ~np.any(E != 0, axis=1)  # cells held at 0 (the centre of free/symmetric)
                if pinned.any():
                    v = v - v[pinned].mean()
                out[key] = device_array(np.linalg.lstsq(E, v, rcond=None)[0])
        if self.fit_diameter:
            frac = min(max((diameter_m or 0.97 * self.d_max_m) / self.d_max_m, 1e-3), 1 - 1e-3)
            out["diam"] = device_array(logit(frac))
        for key in ("gain_db", "phase0"):
            if template.has(key):
                out[key] = device_array(getattr(template, key))
        return LineParams(**out)

    def symmetries(self) -> dict[str, Callable[[LineParams], LineParams]]:
        """Candidate symmetries of the data: maps of the raw parameters that leave some observable
        unchanged, named. `time reversal` (every lag -> -lag, phase offset negated: conjugates every
        cell amplitude, which mirrors the far-field |lobe| in angle) and `mirror` (y -> -y across
        the face, which mirrors it too), and both together (leaves the far-field |lobe| exactly
        unchanged). Whether the DATA are symmetric under one is not decided here: the error budget
        (`fit.uncertainty`) refits from the mapped parameters and compares the costs. Maps that
        change nothing for this model (mirror of a symmetric profile) are left out."""

        def per_cell(profile, p, sign, flip):
            E = self.expansion(profile)
            v = E @ np.asarray(p, float)
            v = sign * (v[::-1] if flip else v)
            return device_array(np.linalg.lstsq(E, v, rcond=None)[0])

        def make(flip: bool, reverse: bool):
            def g(params: LineParams) -> LineParams:
                q = params
                if q.w is not None and flip:
                    q = dataclasses.replace(q, w=per_cell(self.weights, q.w, 1.0, True))
                if q.lag is not None:
                    q = dataclasses.replace(q, lag=per_cell(self.lags, q.lag, -1.0 if reverse else 1.0, flip))
                if q.phase0 is not None and reverse:
                    q = dataclasses.replace(q, phase0=device_array(-np.asarray(q.phase0)))
                return q

            return g

        mirror_changes = any(p == "free" or (p == "smooth" and not self.symmetric) for p in (self.weights, self.lags))
        out = {}
        if self.lags != "uniform":
            out["time reversal"] = make(False, True)
        if mirror_changes:
            out["mirror"] = make(True, False)
            if self.lags != "uniform":
                out["mirror and time reversal"] = make(True, True)
        return out


def soft_floor_db(level_db, floor_db):
    """10 log10(10^(L/10) + 10^(F/10)): equals L well above the floor, F at deep nulls, smooth.
    JAX arrays (and tracers) in, JAX out; host values in, NumPy out (no XLA program)."""
    xp = jnp if isinstance(level_db, jax.Array) else np
    return xp.logaddexp(level_db * (math.log(10) / 10), floor_db * (math.log(10) / 10)) * (10 / math.log(10))


@small_jit
def physical_of(spec: ModelFamily, params: FamilyParams) -> dict:
    """`spec.physical(params)` as one program (called outside a program, each of its ~15
    operations would compile a program of its own in a fresh process)."""
    return spec.physical(params)


def lobe_model_db(spec: ModelFamily, params: FamilyParams, lobe_transfer):
    """Model lobe level in dB (re the transfer's units, plus the fitted gain) at the measured angles."""
    a = spec.amplitudes(params)
    p = jnp.asarray(lobe_transfer) @ a
    gain = getattr(params, "gain_db", None)
    return 10 * jnp.log10(jnp.abs(p) ** 2 + 1e-300) + (0.0 if gain is None else gain)


def wave_model_phase(spec: ModelFamily, params: FamilyParams, wave_transfer):
    """Model carrier phase in the rig's convention (-arg p) plus the fitted offset, radians."""
    a = spec.amplitudes(params)
    p = jnp.asarray(wave_transfer) @ a
    phase0 = getattr(params, "phase0", None)
    return -jnp.angle(p) + (0.0 if phase0 is None else phase0)
