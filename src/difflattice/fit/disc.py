"""The circular-transducer ("disc") model family: a disc of ring source cells for fitting.

A circular transducer is modelled as it is: a flat disc of ring cells of an axisymmetric (r-z)
lattice, ring i spanning radii [r_in_i, r_out_i] (`DiscSpec.ring_edges_m`), each with a complex
amplitude a_i = w_i exp(i omega tau_i) (time convention exp(-i omega t), like `fit.model`).
The observables are linear in the amplitudes, p = T a, with T the ring transfer matrices
(`fit.transfer_disc`); `DiscSpec` has the interface of `fit.model.ModelSpec` (`init_params`,
`physical`, `amplitudes`, `n_cells`, `y_m`, ...), so `fit.solve.fit` and `fit.report` run it
unchanged.

Parameterisation (every fitted quantity is an unconstrained array, as in `fit.model`):

- radius a = a_max sigmoid(d) (raw key "diam", D = 2a = D_max sigmoid(d), the same map as the
  line model's, so `fit.solve`'s diameter scan applies). The disc is made of whole rings: the
  rim ring carries the part of its area inside a, the exact area fraction
  f = (a^2 - r_in^2) / (r_out^2 - r_in^2) (`rim = "area"`), or by default (`rim = "moments"`,
  `rim_fraction`) weights on the rim ring and the one inside it that give the rim's exact area
  AND its exact second moment integral r^2 dA (measured for a 38.4 mm piston at 50 kHz, 20 cells
  per wavelength, exact ring transfers: the model's field at the true radius is within 0.0005 dB
  of the piston's over the main lobe and 0.04 deg on the 16.5 mm wavefront, against 0.004-0.04 dB
  and 0.17 deg with the area fraction). Either is continuous in a and differentiable except
  where the rim crosses a ring edge (where the derivative jumps by O(dr / a));
- weights w = exp(u) > 0 with u a profile; a common log-weight is the fitted gain, so the
  profiles have no constant term (the centre ring's u is 0 for "free");
- lags tau = (T/2) tanh(v) in (-T/2, T/2), T the drive period; a common lag is the fitted phase
  offset (no constant term; the centre ring's lag is 0 for "free").

Profiles (`weights` and `lags` each), as functions of the ring-centre radius r:

- "uniform": no parameters (a piston);
- "free": one parameter per ring (a weak smoothness prior in `fit.solve` removes the
  non-radiating ring-to-ring oscillations);
- "smooth": `n_basis` even Chebyshev polynomials T_2(r/a), T_4(r/a), ... (no T_0);
- "rim_taper": 1 outside a rim zone of width b, then a raised-cosine step S(t) = sin^2(pi t / 2),
  t = (r - (a - b)) / b in [0, 1], to the rim value: w = 1 - (1 - e) S with e = exp(p0) the
  weight at the rim, tau = tau_e S with tau_e = (T/2) tanh(p0) the lag at the rim; the width
  b = a sigmoid(p1) is a second parameter unless `rim_width_m` fixes it (then one parameter).

The numerical profile functions are also exposed in NumPy (`profile_values`), so a ground truth
(`capture.groundtruth.Disc`) can be built from the same functional forms.
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

DiscProfile = Literal["uniform", "free", "smooth", "rim_taper"]
DISC_PROFILES = ("uniform", "free", "smooth", "rim_taper")
AxisLayout = Literal["face", "node"]
DEFAULT_RIM_WIDTH_FRACTION = 0.15
"""Initial rim-zone width b / a of a "rim_taper" profile (its taper starts flat: e = 1, tau_e = 0)."""


class DiscParams(FamilyParams):
    """Raw (unconstrained) parameters of the disc family (`DiscSpec`); None where not fitted.
    Fields in alphabetical (`ravel_pytree`) order."""

    diam: Float[Array, ""] | None = None
    """Diameter, logit(D / D_max) (radius a = a_max sigmoid(diam), a_max the modelled disc's);
    None when the diameter is held at `DiscSpec.diameter_m`."""
    gain_db: Float[Array, ""] | None = None
    """Level offset of the lobe, dB (the transfer's units to the data's); None without lobe data."""
    lag: Float[Array, " n_lag"] | None = None
    """Lag profile, artanh(2 tau / T) (tau = (T/2) tanh(.), T the period): even Chebyshev
    coefficients in r/a ("smooth"), per ring 1..n-1 with ring 0 pinned at 0 ("free"), or a rim
    taper's [artanh(2 tau_rim / T), logit(b / a)] (the width only when not fixed); None for
    "uniform"."""
    phase0: Float[Array, ""] | None = None
    """Carrier phase offset of the wavefront, rad; None without wavefront data."""
    w: Float[Array, " n_w"] | None = None
    """Log-weight profile (w = exp(.), relative to the centre ring): as for `lag`, a rim taper's
    [log(rim weight), logit(b / a)]; None for "uniform"."""


def ring_edges(n_rings: int, dr_m: float, axis: AxisLayout = "face") -> np.ndarray:
    """(n_rings, 2) inner and outer radii (m) of the ring cells of an r-z lattice with cells of
    `dr_m`: with the axis on a cell face (`"face"`) ring i spans [i, i + 1] dr; with a node on the
    axis (`"node"`) ring 0 is the disc [0, dr/2] and ring i spans [i - 1/2, i + 1/2] dr."""
    if n_rings < 1 or not dr_m > 0:
        raise ValueError(f"n_rings = {n_rings} must be >= 1 and dr_m = {dr_m} > 0")
    i = np.arange(n_rings, dtype=float)
    if axis == "face":
        return np.stack([i, i + 1], 1) * dr_m
    if axis == "node":
        return np.stack([np.maximum(i - 0.5, 0.0), i + 0.5], 1) * dr_m
    raise ValueError(f"axis = {axis!r}; allowed: 'face' (axis on a cell face), 'node' (a node on the axis)")


def area_fraction(edges_m, radius_m):
    """Fraction of each ring's area inside radius `radius_m` (jnp; differentiable in the radius)."""
    r_in, r_out = edges_m[:, 0], edges_m[:, 1]
    return _clip01((radius_m**2 - r_in**2) / (r_out**2 - r_in**2))


def _clip01(x):
    """clip(x, 0, 1) differentiated through a select, not `jnp.clip`: JAX differentiates clip by
    equality of its operand with its result, which XLA can break by a one-ulp recomputation in
    another fusion, silently dropping the gradient under `jit` (see `lattice/geometry.py`)."""
    return jnp.where(x < 0, 0.0, jnp.where(x > 1, 1.0, x))


@small_jit  # one program (called eagerly by the fit's bookkeeping, its ~40 operations ran one by one)
def rim_fraction(edges_m, radius_m):
    """Per-ring factors that make a disc of radius `radius_m` out of whole rings with the exact
    area AND the exact second moment integral r^2 dA of the partial rim: the rim ring m (the one
    containing the radius) gets x and ring m - 1 gets 1 + y, with (x, y) solving

        x A_m + y A_(m-1) = pi (a^2 - r_m^2),   x S_m + y S_(m-1) = pi (a^4 - r_m^4) / 2

    (A_k, S_k: area and second moment of ring k). The area fraction alone (`area_fraction`) puts
    the rim's partial area at the whole ring's radii: its second moment is off by
    pi/2 (a^2 - r_m^2)(r_(m+1)^2 - a^2), a disc about f (1 - f) dr^2 / a wider in its main lobe
    (f the rim ring's fraction). Continuous in the radius (x = y = 0 as the rim enters a ring,
    x = 1, y = 0 as it fills it) and differentiable inside each ring. A radius inside ring 0 uses
    the area fraction."""
    r_in, r_out = edges_m[:, 0], edges_m[:, 1]
    n = r_in.shape[0]
    m = jnp.clip(jnp.sum(r_out <= radius_m), 0, n - 1)
    A = jnp.pi * (r_out**2 - r_in**2)
    S = 0.5 * jnp.pi * (r_out**4 - r_in**4)
    a_rim = jnp.pi * (radius_m**2 - r_in[m] ** 2)
    s_rim = 0.5 * jnp.pi * (radius_m**4 - r_in[m] ** 4)
    mp = jnp.maximum(m - 1, 0)
    det = A[m] * S[mp] - S[m] * A[mp]
    safe = jnp.where(m > 0, det, 1.0)
    x = jnp.where(m > 0, (a_rim * S[mp] - s_rim * A[mp]) / safe, a_rim / A[m])
    y = jnp.where(m > 0, (A[m] * s_rim - S[m] * a_rim) / safe, 0.0)
    k = jnp.arange(n)
    return jnp.where(k < m, 1.0, 0.0) + jnp.where(k == m, x, 0.0) + jnp.where((k == mp) & (m > 0), y, 0.0)


def _even_chebyshev(u, n: int, first: int = 1):
    """(len(u), n) even Chebyshev polynomials T_2j(u), j = first .. first + n - 1, by the
    recurrence (defined, and smooth, for |u| slightly above 1: the rim ring's centre)."""
    deg = [2 * (j + first) for j in range(n)]
    t_prev, t = jnp.ones_like(u), u
    out = {0: t_prev, 1: t}
    for d in range(2, max(deg + [1]) + 1):
        t_prev, t = t, 2 * u * t - t_prev
        out[d] = t
    return jnp.stack([out[d] for d in deg], 1)


def smooth_step(t):
    """Raised-cosine step: 0 for t <= 0, sin^2(pi t / 2) on [0, 1], 1 for t >= 1 (C1)."""
    t = _clip01(t)
    return jnp.sin(0.5 * math.pi * t) ** 2


@dataclass(frozen=True)
class DiscSpec(ModelFamily[DiscParams]):
    """Static description of a disc model: `n_cells` ring cells (rings 0 .. n_cells - 1 from the
    axis) of width `dx_m` (the lattice's cell size; the field names are `ModelSpec`'s, so code
    written for the line model, e.g. a refit at another resolution by `dataclasses.replace(spec,
    n_cells=..., dx_m=...)`, works unchanged; `n_rings` and `dr_m` are aliases) at
    `frequency_hz`, the weight and lag profiles ("symmetric" is accepted as "free": one value per
    ring is already symmetric), `n_basis` (smooth profiles), whether the diameter is fitted and
    its initial (or fixed) value `diameter_m` (default: 0.97 x the modelled disc, 2 n_cells dx),
    `rim_width_m` (fixes a rim taper's width), the lattice layout at the axis (`axis`), how the
    rim ring is weighted (`rim`, see `rim_fraction`) and what surrounds the face (`baffle`:
    "rigid", "none" or "can"; the transfer, `fit.transfer_disc.disc_transfer`, models it; here it
    is recorded for reports)."""

    n_cells: int
    dx_m: float
    frequency_hz: float
    weights: DiscProfile = "uniform"
    lags: DiscProfile = "uniform"
    n_basis: int = 2
    fit_diameter: bool = True
    diameter_m: float | None = None
    rim_width_m: float | None = None
    axis: AxisLayout = "face"
    rim: Literal["moments", "area"] = "moments"
    baffle: Literal["rigid", "none", "can"] = "rigid"

    kind: ClassVar[str] = "disc"  # the family's name (a class attribute, not a field)
    symmetric = True  # a disc is symmetric about its axis (ModelSpec's field, for reports)

    def __post_init__(self):
        for name in ("weights", "lags"):
            v = getattr(self, name)
            if v == "symmetric":  # the line model's mirror-symmetric per-cell profile: a ring's value
                object.__setattr__(self, name, "free")
                continue
            if v not in DISC_PROFILES:
                raise ValueError(f"disc model {name} = {v!r}; allowed: {', '.join(DISC_PROFILES)}")
        if self.n_cells < 2:
            raise ValueError(f"n_cells = {self.n_cells} rings must be >= 2 (the modelled disc's radius in cells)")
        if not self.dx_m > 0 or not self.frequency_hz > 0:
            raise ValueError(f"dx_m = {self.dx_m} m and frequency_hz = {self.frequency_hz} Hz must be > 0")
        if self.n_basis < 1:
            raise ValueError(f"n_basis = {self.n_basis} must be >= 1")
        if self.diameter_m is not None and not 0 < self.diameter_m <= self.d_max_m * (1 + 1e-12):
            raise ValueError(
                f"diameter_m = {self.diameter_m} m must be in (0, {self.d_max_m:.6g}] m, the modelled "
                f"disc of {self.n_cells} rings of {self.dx_m:.4g} m; add rings or correct the diameter"
            )
        if self.rim_width_m is not None and not self.rim_width_m > 0:
            raise ValueError(f"rim_width_m = {self.rim_width_m} m must be > 0 (or None: fitted)")
        ring_edges(self.n_cells, self.dx_m, self.axis)  # checks the layout
        if self.baffle not in ("rigid", "none", "can"):
            raise ValueError(f"baffle = {self.baffle!r}; allowed: 'rigid', 'none', 'can'")
        if self.rim not in ("moments", "area"):
            raise ValueError(f"rim = {self.rim!r}; allowed: 'moments' (exact area and second moment), 'area'")

    # -- geometry ---------------------------------------------------------------------------
    @property
    def n_rings(self) -> int:
        return self.n_cells

    @property
    def dr_m(self) -> float:
        """Ring width (m): the lattice's cell size."""
        return self.dx_m

    @property
    def edge_softness_m(self) -> float:
        """Length scale of the rim (m): one ring (the rim is sharp; bounds on the diameter are
        judged against it)."""
        return self.dx_m

    @property
    def reference_cells(self) -> tuple[int, ...]:
        """The cell that profiles are referred to: the centre ring (the line model: its centre)."""
        return (0,)

    @property
    def ring_edges_m(self) -> np.ndarray:
        return ring_edges(self.n_rings, self.dr_m, self.axis)

    @property
    def r_m(self) -> np.ndarray:
        """Ring-centre radii (m): the midpoint of each ring's radial extent."""
        e = self.ring_edges_m
        return 0.5 * (e[:, 0] + e[:, 1])

    @property
    def y_m(self) -> np.ndarray:
        """Positions for plots of per-cell values across the face: the ring radii (m)."""
        return self.r_m

    @property
    def d_max_m(self) -> float:
        return 2.0 * float(self.ring_edges_m[-1, 1])

    @property
    def period_s(self) -> float:
        return 1.0 / self.frequency_hz

    # -- profiles ---------------------------------------------------------------------------
    def _n_params(self, profile: str) -> int:
        if profile == "uniform":
            return 0
        if profile == "free":
            return self.n_rings - 1
        if profile == "smooth":
            return self.n_basis
        return 1 if self.rim_width_m is not None else 2  # rim_taper

    def _shape(self, profile: str, p, radius):
        """Raw profile values at the ring centres (log-weight or pre-tanh lag), and, for a rim
        taper, (rim value, step S) separately: returns (values, None) or (p0, S)."""
        r = jnp.asarray(self.r_m)
        if profile == "free":
            return jnp.concatenate([jnp.zeros(1, p.dtype), p]), None
        if profile == "smooth":
            return _even_chebyshev(r / radius, self.n_basis) @ p, None
        b = self._rim_width(p, radius)  # rim_taper
        return p[0], smooth_step((r - (radius - b)) / b)

    def _rim_width(self, p, radius):
        if self.rim_width_m is not None:
            b = jnp.asarray(self.rim_width_m)
            return jnp.where(b <= radius, b, radius)  # min(b, radius) by a select (see `_clip01`)
        return radius * jax.nn.sigmoid(p[1])

    # -- parameters -------------------------------------------------------------------------
    def init_params(self) -> DiscParams:
        """Initial raw parameters: uniform weights, no lags, the initial diameter (default
        0.97 x the modelled disc), no gain, no phase offset."""
        p: dict = {"gain_db": jnp.asarray(0.0), "phase0": jnp.asarray(0.0)}
        for key, profile in (("w", self.weights), ("lag", self.lags)):
            n = self._n_params(profile)
            if n:
                v = jnp.zeros(n)
                if profile == "rim_taper" and n == 2:
                    f = DEFAULT_RIM_WIDTH_FRACTION
                    v = v.at[1].set(logit(f))
                p[key] = v
        if self.fit_diameter:
            d0 = self.diameter_m or 0.97 * self.d_max_m
            frac = min(max(d0 / self.d_max_m, 1e-3), 1 - 1e-3)
            p["diam"] = jnp.asarray(logit(frac))
        return DiscParams(**p)

    def radius_m(self, params: DiscParams):
        """The disc's radius (m) from raw parameters."""
        if params.diam is not None:
            return 0.5 * self.d_max_m * jax.nn.sigmoid(params.diam)
        return jnp.asarray(0.5 * (self.diameter_m or self.d_max_m))

    def physical(self, params: DiscParams) -> dict:
        """Raw parameters -> physical: `weights` (per ring, times the ring's area fraction inside
        the radius), `weights_raw` (the profile alone), `lags_s`, `ring_fraction` (each ring's share of the disc, see `rim_fraction`), `diameter_m`,
        `gain_db`, `phase0_rad`, and the rim-taper quantities where used (`rim_weight`,
        `rim_width_m`, `rim_lag_s`, `rim_lag_width_m`)."""
        a = self.radius_m(params)
        half_t = 0.5 * self.period_s
        out = {}
        w = jnp.ones(self.n_rings)
        if params.w is not None:
            if self.weights == "rim_taper":
                p0, s = self._shape("rim_taper", params.w, a)
                e = jnp.exp(p0)
                w = 1.0 - (1.0 - e) * s
                out["rim_weight"] = e
                out["rim_width_m"] = self._rim_width(params.w, a)
            else:
                w = jnp.exp(self._shape(self.weights, params.w, a)[0])
        lag = jnp.zeros(self.n_rings)
        if params.lag is not None:
            if self.lags == "rim_taper":
                p0, s = self._shape("rim_taper", params.lag, a)
                tau_e = half_t * jnp.tanh(p0)
                lag = tau_e * s
                out["rim_lag_s"] = tau_e
                out["rim_lag_width_m"] = self._rim_width(params.lag, a)
            else:
                lag = half_t * jnp.tanh(self._shape(self.lags, params.lag, a)[0])
        edges = jnp.asarray(self.ring_edges_m)
        frac = rim_fraction(edges, a) if self.rim == "moments" else area_fraction(edges, a)
        return {
            "weights": w * frac,
            "weights_raw": w,
            "lags_s": lag,
            "ring_fraction": frac,
            "diameter_m": 2.0 * a,
            "gain_db": jnp.asarray(0.0) if params.gain_db is None else params.gain_db,
            "phase0_rad": jnp.asarray(0.0) if params.phase0 is None else params.phase0,
            **out,
        }

    def amplitudes(self, params: DiscParams):
        """Complex ring amplitudes a_i = w_i f_i exp(i omega tau_i) (exp(-i omega t) convention):
        the normal velocity of ring i relative to a uniform piston, times its area fraction."""
        ph = self.physical(params)
        return ph["weights"] * jnp.exp(1j * 2 * math.pi * self.frequency_hz * ph["lags_s"])

    def truth_params(
        self, *, diameter_m: float, w=None, lag=None, gain_db: float = 0.0, phase0_rad: float = 0.0
    ) -> DiscParams:
        """Raw parameters for a given diameter (m) and raw profile arrays (`w`, `lag`), e.g. to
        emulate data from a known disc."""
        p: dict = {"gain_db": jnp.asarray(gain_db), "phase0": jnp.asarray(phase0_rad)}
        if self.fit_diameter:
            frac = diameter_m / self.d_max_m
            if not 0 < frac < 1:
                raise ValueError(
                    f"diameter_m = {diameter_m} m must lie inside the modelled disc ({self.d_max_m:.6g} m)"
                )
            p["diam"] = jnp.asarray(logit(frac))
        for key, profile, v in (("w", self.weights, w), ("lag", self.lags, lag)):
            n = self._n_params(profile)
            if n:
                v = jnp.zeros(n) if v is None else jnp.asarray(v, float)
                if v.shape != (n,):
                    raise ValueError(f"{key} has shape {v.shape}; the {profile!r} profile takes ({n},)")
                p[key] = v
        return DiscParams(**p)

    # -- structure of the parameterisation (labels, bounds, warm starts, symmetries) ---------
    def raw_labels(self, params: DiscParams) -> list[str]:
        """Names of the raw parameters in `jax.flatten_util.ravel_pytree(params)` order: smooth
        profile coefficients `w.T2`, `w.T4`, ... (even Chebyshev degree in r/a), free ones `w[k]`
        (ring k), a rim taper's `w.rim_log` / `lag.rim_atanh` (rim value) and `*.rim_width_logit`,
        `diameter.logit`, `gain_db`, `phase0_rad`."""
        out: list[str] = []
        for key in params.names():
            if key in ("w", "lag"):
                profile = self.weights if key == "w" else self.lags
                if profile == "smooth":
                    out += [f"{key}.T{2 * (i + 1)}" for i in range(self.n_basis)]
                elif profile == "free":
                    out += [f"{key}[{k}]" for k in range(1, self.n_rings)]
                else:
                    out += [f"{key}.rim_log" if key == "w" else f"{key}.rim_atanh"]
                    if self.rim_width_m is None:
                        out.append(f"{key}.rim_width_logit")
            else:
                out.append({"diam": "diameter.logit", "gain_db": "gain_db", "phase0": "phase0_rad"}.get(key, key))
        return out

    def bounds(self) -> dict:
        """Physical bounds the parameterisation imposes: `diameter_mm` in (0, modelled disc),
        `lag_us` in (-T/2, T/2) (a lag is defined modulo the period)."""
        half_us = 0.5 * self.period_s * 1e6
        return {"diameter_mm": (0.0, self.d_max_m * 1e3), "lag_us": (-half_us, half_us)}

    def expansion(self, profile: str, radius_m: float | None = None) -> np.ndarray:
        """(n_rings, n_params) matrix of the linear map from a "free" or "smooth" profile's raw
        parameters to the per-ring raw values (log weight, or artanh(2 lag / T)), at `radius_m`
        (smooth profiles are polynomials in r / a; default: the initial radius); (n_rings, 0) for
        "uniform". A rim taper is not linear in its parameters: ValueError."""
        if profile == "uniform":
            return np.zeros((self.n_rings, 0))
        if profile == "free":
            return np.eye(self.n_rings)[:, 1:]
        if profile == "smooth":
            a = radius_m if radius_m is not None else 0.5 * (self.diameter_m or 0.97 * self.d_max_m)
            return np.asarray(_even_chebyshev(jnp.asarray(self.r_m / a), self.n_basis))
        raise ValueError(f"the {profile!r} disc profile is not linear in its parameters (no expansion matrix)")

    def params_from_profiles(
        self, log_weights, lag_args, diameter_m: float | None, template: FamilyParams
    ) -> DiscParams:
        """Raw parameters of this model closest (least squares) to per-ring raw values
        (`log_weights` = log w_i, `lag_args` = artanh(2 tau_i / T), at this model's rings) and the
        `diameter_m`, e.g. for a warm start at another resolution. A rim taper's parameters are
        functions of r / a, independent of the rings: they are copied from `template` (same
        profile) or start flat. Offsets (gain, phase0) are copied from `template`."""
        a = 0.5 * (diameter_m or self.diameter_m or 0.97 * self.d_max_m)
        out: dict = {}
        init = self.init_params()
        for key, profile, v in (("w", self.weights, log_weights), ("lag", self.lags, lag_args)):
            n = self._n_params(profile)
            if not n:
                continue
            if profile == "rim_taper" or v is None:
                t = getattr(template, key, None)
                out[key] = jnp.asarray(t) if t is not None and np.shape(t) == (n,) else getattr(init, key)
                continue
            v = np.asarray(v, float)
            inside = self.r_m < a
            E = self.expansion(profile, a)[inside]
            out[key] = jnp.asarray(np.linalg.lstsq(E, (v - v[0])[inside], rcond=None)[0])
        if self.fit_diameter:
            frac = min(max(2 * a / self.d_max_m, 1e-3), 1 - 1e-3)
            out["diam"] = jnp.asarray(logit(frac))
        for key in ("gain_db", "phase0"):
            if template.has(key):
                out[key] = jnp.asarray(getattr(template, key))
        return DiscParams(**out)

    def symmetries(self) -> dict[str, Callable[[DiscParams], DiscParams]]:
        """Maps of the raw parameters that leave some observable (nearly) unchanged, named:
        `time reversal` (every lag -> -lag and the phase offset negated: conjugates the ring
        amplitudes, which leaves a far-field |lobe| unchanged: the lag sign is not determined by a
        lobe alone). A disc has no mirror symmetry to add (it is symmetric by construction)."""
        if self.lags == "uniform":
            return {}

        def reverse(params: DiscParams) -> DiscParams:
            q = params
            if q.lag is not None:
                lag = jnp.asarray(q.lag)
                q = dataclasses.replace(q, lag=lag.at[0].set(-lag[0]) if self.lags == "rim_taper" else -lag)
            if q.phase0 is not None:
                q = dataclasses.replace(q, phase0=-jnp.asarray(q.phase0))
            return q

        return {"time reversal": reverse}


def profile_values(
    profile: str,
    raw,
    r_over_a,
    *,
    kind: Literal["weights", "lags"],
    period_s: float,
    rim_width_over_a: float | None = None,
) -> np.ndarray:
    """NumPy: a profile of `DiscSpec` at radii `r_over_a` (r / a, continuous), from its raw
    parameters (`raw`, as in `DiscSpec.init_params`; for "rim_taper" with a fixed width, give
    `rim_width_over_a` and raw = [p0]). Returns weights (kind="weights") or lags in s."""
    u = np.asarray(r_over_a, float)
    raw = np.asarray(raw, float)
    if profile == "uniform":
        v = np.zeros_like(u)
    elif profile == "smooth":
        v = np.asarray(_even_chebyshev(jnp.asarray(u), len(raw))) @ raw
    elif profile == "rim_taper":
        b = rim_width_over_a if rim_width_over_a is not None else 1 / (1 + math.exp(-raw[1]))
        s = np.asarray(smooth_step(jnp.asarray((u - (1 - b)) / b)))
        if kind == "weights":
            return 1 - (1 - math.exp(raw[0])) * s
        return 0.5 * period_s * math.tanh(raw[0]) * s
    else:
        raise ValueError(f"profile_values: {profile!r} has no continuous form (use uniform, smooth or rim_taper)")
    return np.exp(v) if kind == "weights" else 0.5 * period_s * np.tanh(v)
