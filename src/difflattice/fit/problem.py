"""The residual function of a fit: the data, transfer matrices and options as a `Problem`
(arrays and static structure), its residuals (soft-floored lobe dB, the chord of the wavefront
phase, robust losses as sqrt(2 rho), the smoothness prior), the start and the jitted cost and
residuals the solve steps on. See `fit.solve` for the losses' rationale."""

from __future__ import annotations

import math
from typing import TYPE_CHECKING

import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np

from ..transforms import logit
from .data import LobeData, WaveData
from .family import FamilyParams, ModelFamily
from .model import device_array, lobe_model_db, soft_floor_db, wave_model_phase
from .programs import small_jit
from .transfer import Transfer

if TYPE_CHECKING:
    from .solve import FitOptions

LOSSES = ("l2", "huber", "cauchy")


def robust_factor(a, loss: str, scale: float):
    """phi(a) = sqrt(2 rho(a)) / a for residual magnitudes `a` >= 0 (sigma units), so that
    (phi(|r|) r)^2 = 2 rho(r): 1 for "l2"; Huber and Cauchy with scale `scale` (1 inside)."""
    if loss == "l2":
        return jnp.ones_like(a)
    u = a / scale
    if loss == "huber":
        big = u > 1
        us = jnp.where(big, u, 1.0)
        return jnp.where(big, jnp.sqrt(2 * us - 1) / us, 1.0)
    if loss == "cauchy":
        u2 = u * u
        small = u2 < 1e-6
        u2s = jnp.where(small, 1.0, u2)
        return jnp.sqrt(jnp.where(small, 1 - u2 / 2 + u2 * u2 / 3, jnp.log1p(u2s) / u2s))
    raise ValueError(f"loss = {loss!r}; allowed: {', '.join(LOSSES)}")


class Problem(eqx.Module):
    """The residual function's data (arrays) and structure (static)."""

    spec: ModelFamily = eqx.field(static=True)
    lobe_T: jax.Array | None
    lobe_db: jax.Array | None
    lobe_sigma: jax.Array | None
    lobe_floor: float | None = eqx.field(static=True)
    wave_T: jax.Array | None
    wave_phase: jax.Array | None
    wave_sigma: jax.Array | None
    w_lobe: float = eqx.field(static=True)
    w_wave: float = eqx.field(static=True)
    smoothness_sigma: float = eqx.field(static=True, default=0.05)
    loss: str = eqx.field(static=True, default="l2")
    loss_scale: float = eqx.field(static=True, default=3.0)

    def data_residuals(self, params: FamilyParams) -> dict:
        """Normalised data residuals (model - data) / sigma per observable, before weights and the
        robust transform: lobe (soft-floored dB) and wave (2 sin(d/2), the chord of the phase
        difference d on the unit circle)."""
        out = {}
        if self.lobe_T is not None:
            assert self.lobe_sigma is not None  # given with the lobe (`build_problem`)
            m = lobe_model_db(self.spec, params, self.lobe_T)
            out["lobe"] = (
                soft_floor_db(m, self.lobe_floor) - soft_floor_db(self.lobe_db, self.lobe_floor)
            ) / jnp.asarray(self.lobe_sigma)
        if self.wave_T is not None:
            d = wave_model_phase(self.spec, params, self.wave_T) - self.wave_phase
            out["wave"] = 2 * jnp.sin(d / 2) / jnp.asarray(self.wave_sigma)
        return out

    def residuals(self, params: FamilyParams):
        parts = self._smoothness(params)
        if self.lobe_T is not None:
            assert self.lobe_sigma is not None  # given with the lobe (`build_problem`)
            m = lobe_model_db(self.spec, params, self.lobe_T)
            r = (soft_floor_db(m, self.lobe_floor) - soft_floor_db(self.lobe_db, self.lobe_floor)) / self.lobe_sigma
            parts.append(math.sqrt(self.w_lobe) * r * robust_factor(jnp.abs(r), self.loss, self.loss_scale))
        if self.wave_T is not None:
            assert self.wave_sigma is not None  # given with the wavefront (`build_problem`)
            d = wave_model_phase(self.spec, params, self.wave_T) - self.wave_phase
            f = math.sqrt(self.w_wave) * robust_factor(
                2 * jnp.abs(jnp.sin(d / 2)) / self.wave_sigma, self.loss, self.loss_scale
            )
            parts.append(f * jnp.sin(d) / self.wave_sigma)
            parts.append(f * (1 - jnp.cos(d)) / self.wave_sigma)
        return jnp.concatenate(parts)

    def _smoothness(self, params: FamilyParams) -> list:
        """Per-cell profiles have components that do not radiate (cell-to-cell oscillations
        beyond the wavenumber k): a weak prior on second differences of log-weight and lag phase
        (`smoothness_sigma` per cell) removes that null space, so free fits converge."""
        spec, out = self.spec, []
        for key, profile in (("w", spec.weights), ("lag", spec.lags)):
            if params.has(key) and profile in ("free", "symmetric"):
                ph = spec.physical(params)
                v = jnp.log(ph["weights_raw"]) if key == "w" else 2 * math.pi * spec.frequency_hz * ph["lags_s"]
                out.append((v[2:] - 2 * v[1:-1] + v[:-2]) / self.smoothness_sigma)
        return out


def build_problem(
    spec: ModelFamily, transfer: Transfer, lobe: LobeData | None, wave: WaveData | None, o: FitOptions
) -> Problem:
    """Bundle the data, transfer matrices and options into the residual function's `Problem`."""
    if lobe is None and wave is None:
        raise ValueError("nothing to fit: give lobe data, wavefront data or both")
    if transfer.n_cells != spec.n_cells:
        raise ValueError(f"transfer has {transfer.n_cells} cells but the model {spec.n_cells}")
    return Problem(
        spec=spec,
        lobe_T=None if lobe is None else device_array(transfer.lobe),
        lobe_db=None if lobe is None else device_array(lobe.level_db),
        lobe_sigma=None if lobe is None else device_array(lobe.sigma_db),
        lobe_floor=None if lobe is None else float(np.max(lobe.level_db) - o.floor_db),
        wave_T=None if wave is None else device_array(transfer.wave),
        wave_phase=None if wave is None else device_array(wave.phase_rad),
        wave_sigma=None if wave is None else device_array(wave.sigma_rad),
        w_lobe=o.lobe_weight,
        w_wave=o.wave_weight,
        smoothness_sigma=o.smoothness_sigma,
        loss=o.loss,
        loss_scale=float(o.loss_scale),
    )


@small_jit
def _residuals(problem: Problem, params: FamilyParams):
    return problem.residuals(params)


def initial_params(problem: Problem, params: FamilyParams | None = None) -> FamilyParams:
    """Start from the model's initial parameters with the gain and phase offset set in closed form,
    and (when it is fitted) the diameter chosen by a scan over 0.5-1 x the modelled line: the
    lobe's null angles scale with 1/D, so the cost in D has many local minima."""
    spec = problem.spec
    p = spec.init_params() if params is None else params
    # offsets the data cannot see are not parameters (they would make J singular)
    if problem.lobe_T is None:
        p = p.without("gain_db")
    if problem.wave_T is None:
        p = p.without("phase0")
    if p.has("diam") and params is None:
        best: tuple[float, FamilyParams] | None = None
        for frac in np.linspace(0.5, 0.98, 25):
            q = _with_offsets(problem, p.replace(diam=device_array(logit(frac))))
            r = np.asarray(_residuals(problem, q))
            c = float(r @ r)
            if np.isfinite(c) and (best is None or c < best[0]):
                best = (c, q)
        if best is not None:  # else every scanned diameter gave a non-finite cost: the fit says so
            return best[1]
    return _with_offsets(problem, p)


def _with_offsets(problem: Problem, p: FamilyParams) -> FamilyParams:
    if p.has("gain_db"):
        m = np.asarray(_evaluate(problem, p.replace(gain_db=device_array(0.0)))["lobe_db"])
        data = np.asarray(problem.lobe_db)
        top = data > data.max() - 10
        p = p.replace(gain_db=device_array(float(np.median(data[top] - m[top]))))
    if p.has("phase0"):
        m = np.asarray(_evaluate(problem, p.replace(phase0=device_array(0.0)))["wave_phase"])
        d = np.asarray(problem.wave_phase) - m
        p = p.replace(phase0=device_array(float(np.angle(np.mean(np.exp(1j * d))))))
    return p


def _residual_aux(y: FamilyParams, args):
    """The residuals at `y`, with the parameters `free` marks False taken from `held` instead
    (their Jacobian columns are zero, so the solver's steps leave them alone): which parameters
    a stage holds is data, so every stage of a fit runs the same compiled solver programs.
    `held` and `free` (a boolean per parameter) have `y`'s structure."""
    problem, held, free = args
    return problem.residuals(jax.tree_util.tree_map(jnp.where, free, y, held)), None


def _cost_aux(y, args):
    r, _ = _residual_aux(y, args)
    return 0.5 * jnp.sum(r * r), None


def _model_curves(problem: Problem, params: FamilyParams):
    """(model lobe level in dB, model wave phase) at the data points (None where there are no
    data)."""
    lobe = None if problem.lobe_T is None else lobe_model_db(problem.spec, params, problem.lobe_T)
    wave = None if problem.wave_T is None else wave_model_phase(problem.spec, params, problem.wave_T)
    return lobe, wave


def _flat_jacobian(jac: FamilyParams, params: FamilyParams) -> jnp.ndarray:
    """A Jacobian computed w.r.t. parameters `params` (leaves (m, *shape) in their structure), as
    (m, n) in `ravel_pytree` order."""
    cols = [j.reshape(j.shape[0], -1) for j in jax.tree_util.tree_leaves(jac)]
    return jnp.concatenate(cols, axis=1)


def _physical_values(spec: ModelFamily, params: FamilyParams):
    """The physical vector (`fit.result.physical_vector`'s values)."""
    ph = spec.physical(params)
    return jnp.concatenate(
        [
            ph["weights"],
            ph["lags_s"] * 1e6,
            jnp.atleast_1d(ph["diameter_m"] * 1e3),
            jnp.atleast_1d(ph["gain_db"]),
            jnp.atleast_1d(jnp.degrees(ph["phase0_rad"])),
        ]
    )


def _physical_jacobian_of(spec: ModelFamily, params: FamilyParams):
    jac = jax.jacfwd(lambda p: _physical_values(spec, p))(params)
    return _flat_jacobian(jac, params)


@small_jit
def _evaluate(problem: Problem, params: FamilyParams) -> dict:
    """Everything the fit reads at one point, as one program per model structure (in a fresh
    process each program is traced, lowered and compiled: one serves the start's offsets and the
    result): the residuals `r` and their Jacobian `J` (raw parameters, `ravel_pytree` order), the
    data residuals, the physical quantities `phys` and their vector's Jacobian `G`, and the
    models at the data points (`lobe_db`, `wave_phase`)."""
    spec = problem.spec
    lobe, wave = _model_curves(problem, params)
    return {
        "r": problem.residuals(params),
        "J": _flat_jacobian(jax.jacfwd(problem.residuals)(params), params),
        "G": _physical_jacobian_of(spec, params),
        "data_res": problem.data_residuals(params),
        "phys": spec.physical(params),
        "lobe_db": lobe,
        "wave_phase": wave,
    }
