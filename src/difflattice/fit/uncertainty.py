"""Error budgets of fitted transducer parameters: a statistical and a systematic part, the
parameters the data cannot determine named as such, and parameters at a bound reported as bounds.

    budget = error_budget(fitted, transfer, lobe, wave, options,
                          make_transfer=lambda m: <the same transfer at m cells per wavelength>,
                          second_cells_per_wavelength=None, model_families=None)

Quantities: the active diameter (mm), the gain (dB, referred to the centre cell's weight), the
wavefront phase offset (deg, referred to the centre cell's lag), the smooth profiles' Chebyshev
coefficients (every other raw profile parameter, e.g. a disc's rim taper), and per cell across the
face the weight relative to the reference (centre) cell and the lag
relative to the centre cell (µs): the overall scale and a common lag are the gain and the offset,
so only these are defined by the data and comparable between fits.

Per quantity, all 1-sigma-like, combined in quadrature into `total`:

- **statistical**: the Jacobian covariance (J^T J)^+ of the minimised residuals at the solution,
  propagated to the quantity: the noise alone, as if the model were exact;
- **systematic, resolution**: the fit repeated on a second lattice (`second_cells_per_wavelength`,
  default 1.5 x the fit's), the difference scaled to the discretisation error of the nominal
  fit assuming the lattice's second-order convergence: |q_1 - q_2| / |1 - (m_1 / m_2)^2|;
- **systematic, model**: (a) `sys_chi2` = stat * sqrt(max(v - 1, 0)), v the fit's variance factor
  (chi2_red for l2, Huber's M-estimator factor for robust losses): residuals above the noise are
  model error the covariance has to carry; (b) `sys_family`: model averaging's unconditional
  variance about the reported value over alternative model families (`model_families`; default
  n_basis + 1 for smooth profiles, free <-> symmetric for per-cell ones; "free"/"symmetric" asked
  for a smooth model test the taper's shape with a weak prior): each family weighted by its
  Akaike weight (quasi-AIC = chi2 / c + 2 x effective parameters, c the variance factor of the
  richest model; families beyond 10 of the best get none) contributes its shift squared plus the
  extra variance with which it determines the quantity (a family that pins the quantity less well
  says the nominal model's precision rests on its assumptions). Coefficients of another basis
  are the ones that family's per-cell profile implies (inverse-variance weighted projection).
- **total**: the quadrature sum (a 1-sigma-like figure).

Gain and phase offset refer to the lattice's unit source cell, so they get no resolution term.

Identifiability, decided by the data, not hard-coded:

- the model's candidate symmetries (`ModelSpec.symmetries`: time reversal of the lags, mirror
  across the face) are applied to the solution and refitted; when the mapped solution fits as
  well (scaled delta chi2 <= `EQUIVALENT_DELTA_CHI2`), every quantity it changes by more than
  twice its total uncertainty is NAMED undetermined, with the other solution's value (a lobe
  alone cannot tell a lead from a lag);
- directions of the Jacobian's null space make the quantities they move undetermined;
- quantities that are one parameter by construction (the mirror cells of a symmetric profile:
  identical rows of d quantity / d parameters) are listed once;
- cells outside the active aperture (window < 1/2) carry no determined lag or weight.

Bounds: a diameter within max(2 inflated standard errors, 2 edge softnesses) of 0 or of the modelled
line's length, or a lag that close to +-T/2, is pinned there: reported as a one-sided limit ("at
bound", ">= x") with the fix, not as a value +- 0.00.
"""

from __future__ import annotations

import concurrent.futures
import dataclasses
import math
from collections.abc import Callable, Mapping, Sequence
from typing import Any

import numpy as np

from .data import LobeData, WaveData
from .estimates import STATUSES, ErrorBudget, Estimate, coefficient_unit, human_name
from .families import (
    FAMILY_KEYS,
    SUPPORTED_DELTA_QAIC,
    _family,
    default_families,
    family_spread,
    weak_smoothness_sigma,
)
from .family import ModelFamily
from .identify import (
    EQUIVALENT_DELTA_CHI2,
    check_symmetries,
    mark_bounds,
    mark_fixed,
    mark_non_finite,
    mark_null_directions,
    mark_reference_and_inactive,
    mirror_aliases,
)
from .quantities import (
    NUISANCE,
    _on_nominal,
    _values,
    map_params,
    quantities,
    quantities_and_jacobian,
)
from .solve import FitOptions, FitResult, fit
from .transfer import Transfer

__all__ = [
    "EQUIVALENT_DELTA_CHI2",
    "FAMILY_KEYS",
    "STATUSES",
    "SUPPORTED_DELTA_QAIC",
    "ErrorBudget",
    "Estimate",
    "coefficient_unit",
    "default_families",
    "error_budget",
    "human_name",
    "map_params",
    "quantities",
    "second_resolution",
    "weak_smoothness_sigma",
]


def second_resolution(cells_per_wavelength: float, second: float | None = None) -> float:
    """The resolution (cells per wavelength) of the error budget's refit: `second`, else 1.5 x the
    fit's."""
    return float(second or 1.5 * cells_per_wavelength)


def error_budget(
    fitted: FitResult,
    transfer: Transfer,
    lobe: LobeData | None,
    wave: WaveData | None,
    options: FitOptions | None = None,
    *,
    make_transfer: Callable[[float], Transfer] | None = None,
    second_cells_per_wavelength: float | None = None,
    model_families: Sequence[str | Mapping[str, Any]] | None = None,
    symmetries: bool = True,
    progress: bool = False,
) -> ErrorBudget:
    """The error budget of `fitted` (the fit of `fitted.spec` to `lobe`/`wave` with `transfer`
    and `options`; see the module docstring for the method).

    - `make_transfer(cells_per_wavelength) -> Transfer`: the same transfer (same data points and
      modelled line length) at another resolution; None skips the resolution part (the budget
      says so).
    - `second_cells_per_wavelength`: that resolution; None: 1.5 x the fit's.
    - `model_families`: alternative families, each either `ModelSpec` overrides, e.g.
      `{"n_basis": 5}` or `{"weights": "symmetric", "smoothness_sigma": 0.3}` (keys: weights, lags,
      n_basis, symmetric, smoothness_sigma), or a profile name ("free", "symmetric", "smooth")
      applied to every fitted profile ("smooth" for a smooth nominal: n_basis + 1); None:
      `default_families`; [] compares none.
    - `symmetries`: test the model's candidate symmetries (one refit each; see the module).
    - `progress`: print one line per refit.
    - `options`: the fit's settings (default: those `fitted` ran with).

    Refits start from the nominal solution (mapped onto the other model) and use `options`.
    With `make_transfer=None, model_families=[], symmetries=False` no refit runs: the
    statistical part, chi2 inflation, bounds, null directions and mirror aliases only."""
    spec, params = fitted.spec, fitted.params
    options = options or fitted.options or FitOptions()
    say = print if progress else (lambda *a, **k: None)
    vf = fitted.variance_factor
    # the refit at a second resolution runs in a background thread while the quantities and the
    # model-family refits run here (XLA's compilation and the solver's steps release the GIL)
    res = _ResolutionRefit.start(fitted, transfer, lobe, wave, options, make_transfer, second_cells_per_wavelength, say)
    v, names, units, G = quantities_and_jacobian(spec, params, fitted.solved_in)
    cov = fitted.covariance_raw
    stat = (
        np.sqrt(np.clip(np.einsum("ij,jk,ik->i", G, cov, G), 0, None)) if cov is not None else np.full(len(v), np.nan)
    )
    ph = fitted.physical  # spec.physical(params), computed with the result
    window = np.asarray(ph["weights"]) / np.asarray(ph["weights_raw"])
    active = window >= 0.5  # cells inside the active aperture

    fams = default_families(spec) if model_families is None else [_family(spec, f) for f in model_families]
    spread = family_spread(fitted, transfer, lobe, wave, options, fams, names, v, stat, active, say)
    sys_res, resolution, res_notes = res.finish(names, v)

    est = _estimates(spec, names, units, v, stat, stat * math.sqrt(max(vf - 1.0, 0.0)), sys_res, spread.sys_family)
    mark_reference_and_inactive(est, spec, window)
    mark_fixed(est, names, v, G)
    undetermined = mark_null_directions(est, fitted, names, G)
    sym_out: list[dict] = []
    notes = res_notes + spread.notes
    if symmetries:
        sym_out, sym_undetermined, sym_notes = check_symmetries(
            est, fitted, transfer, lobe, wave, options, names, v, say
        )
        undetermined += sym_undetermined
        notes += sym_notes
    mark_bounds(est, fitted, names, np.asarray(ph["lags_s"]), cov)
    aliases, drop = mirror_aliases(est, spec)
    mark_non_finite(est, names)

    scalars = [est[k] for k in names if not k.startswith(("w[", "lag_us["))]
    for e in scalars:
        if e.status == "at_bound":
            undetermined.append(f"{e.name}: {e.note}; reported as the one-sided limit {e.limit}")
        elif e.status == "undetermined" and e.note and not any(e.name in u for u in undetermined):
            undetermined.append(f"{e.name}: {e.note}")
    return ErrorBudget(
        scalars=scalars,
        weights=[est[k] for k in names if k.startswith("w[") and k not in drop],
        lags=[est[k] for k in names if k.startswith("lag_us[") and k not in drop],
        variance_factor=vf,
        resolution=resolution,
        families=spread.families,
        symmetries=sym_out,
        undetermined=undetermined,
        aliases=aliases,
        notes=notes,
    )


def _estimates(
    spec: ModelFamily,
    names: Sequence[str],
    units: Sequence[str],
    v: np.ndarray,
    stat: np.ndarray,
    sys_chi2: np.ndarray,
    sys_res: dict[str, float] | None,
    sys_fam: dict[str, float] | None,
) -> dict[str, Estimate]:
    """Every quantity's estimate before identifiability (status "determined")."""
    y_mm = spec.y_m * 1e3
    est: dict[str, Estimate] = {}
    for i, (k, u) in enumerate(zip(names, units)):
        pos = None
        if k.startswith(("w[", "lag_us[")):
            pos = float(y_mm[int(k[k.index("[") + 1 : -1])])
        est[k] = Estimate(
            name=k,
            unit=u,
            value=float(v[i]),
            stat=float(stat[i]),
            sys_resolution=None if sys_res is None else sys_res.get(k),
            sys_chi2=float(sys_chi2[i]),
            sys_family=None if sys_fam is None else sys_fam.get(k),
            y_mm=pos,
        )
    return est


@dataclasses.dataclass
class _ResolutionRefit:
    """The resolution part: the fit repeated on a second lattice (in a background thread), its
    differences Richardson-scaled to the nominal fit's discretisation error."""

    spec: ModelFamily
    m1: float
    m2: float | None = None
    spec2: ModelFamily | None = None
    future: concurrent.futures.Future | None = None
    reason: str = ""

    @classmethod
    def start(
        cls,
        fitted: FitResult,
        transfer: Transfer,
        lobe: LobeData | None,
        wave: WaveData | None,
        options: FitOptions,
        make_transfer: Callable[[float], Transfer] | None,
        second: float | None,
        say: Callable[..., None],
    ) -> _ResolutionRefit:
        spec, params = fitted.spec, fitted.params
        m1 = float(transfer.info.get("cells_per_wavelength", transfer.grid.cells_per_wavelength))
        if make_transfer is None:
            return cls(spec, m1, reason="no second transfer (make_transfer) given")
        m2 = second_resolution(m1, second)
        if not (m2 > 0 and math.isfinite(m2)) or abs(m2 - m1) < 1e-9:
            raise ValueError(
                f"second_cells_per_wavelength = {m2:g} must be > 0 and differ from the fit's {m1:g} "
                "(e.g. 1.5 x the fit's)"
            )
        say(f"[budget] refit at {m2:g} cells per wavelength (resolution error)")
        T2 = make_transfer(m2)
        spec2 = dataclasses.replace(spec, n_cells=T2.n_cells, dx_m=T2.grid.dx_m)
        pool = concurrent.futures.ThreadPoolExecutor(1, thread_name_prefix="difflattice-budget")
        params2 = map_params(spec, params, spec2, physical=fitted.physical)
        future = pool.submit(fit, spec2, T2, lobe, wave, options, params0=params2)
        pool.shutdown(wait=False)
        return cls(spec, m1, m2, spec2, future)

    def finish(self, names: Sequence[str], v: np.ndarray) -> tuple[dict[str, float] | None, dict, list[str]]:
        """(per-quantity resolution error or None, the budget's "resolution" record, notes)."""
        if self.future is None or self.m2 is None or self.spec2 is None:
            return None, {"measured": False, "reason": self.reason}, []
        f2 = self.future.result()
        m1, m2 = self.m1, self.m2
        factor = 1.0 / abs(1.0 - (m1 / m2) ** 2)
        other = _on_nominal(self.spec, self.spec2, _values(self.spec2, f2.params))
        # the gain and the phase offset refer to the lattice's unit source cell, whose strength and
        # phase change with the cell size: not a property of the transducer, so no resolution term
        sys_res = {k: factor * abs(other[k] - val) for k, val in zip(names, v) if k in other and k not in NUISANCE}
        resolution = {
            "measured": True,
            "cells_per_wavelength": m1,
            "second_cells_per_wavelength": m2,
            "richardson_factor": factor,
            "chi2_reduced": f2.chi2_reduced,
            "converged": f2.converged,
            "values": {k: other[k] for k in ("diameter_mm", "gain_db", "phase0_deg") if k in other},
        }
        notes = []
        if not f2.converged:
            notes.append(
                f"the refit at {m2:g} cells per wavelength did not converge ({f2.result_code}): its "
                "resolution estimate is uncertain"
            )
        return sys_res, resolution, notes
