"""The error budget's quantities (active diameter, gain, phase offset, profile coefficients, per-cell
weights and lags re the centre) as differentiable functions of a fit's parameters, and their
mapping between model families and resolutions."""

from __future__ import annotations

import math

import jax
import jax.numpy as jnp
import numpy as np
from jax.flatten_util import ravel_pytree

from .estimates import coefficient_unit
from .family import FamilyParams, ModelFamily
from .model import device_array, physical_of
from .programs import small_jit
from .result import FitResult, _flat_jacobian

NUISANCE = ("gain_db", "phase0_deg")
"""Offsets whose meaning depends on the lattice's unit source cell (no resolution term)."""
OFFSET_LABELS = ("diameter.logit", "gain_db", "phase0_rad")
"""Raw parameters that are not profile coefficients (their physical forms are budget scalars)."""


def quantities(spec: ModelFamily, params: FamilyParams):
    """(vector, names, units) of the budget's quantities for `params` (differentiable)."""
    ph = spec.physical(params)
    n = spec.n_cells
    mid = list(spec.reference_cells)
    w = ph["weights"]
    wc = jnp.mean(w[jnp.asarray(mid)])
    lag = ph["lags_s"]
    lc = jnp.mean(lag[jnp.asarray(mid)])
    parts, names, units = [], [], []
    if spec.weights != "uniform" or spec.fit_diameter:
        parts.append(w / wc)
        names += [f"w[{k}]" for k in range(n)]
        units += ["re centre"] * n
    if spec.lags != "uniform":
        parts.append((lag - lc) * 1e6)
        names += [f"lag_us[{k}]" for k in range(n)]
        units += ["µs"] * n
    if params.has("diam"):
        parts.append(jnp.atleast_1d(ph["diameter_m"] * 1e3))
        names.append("diameter_mm")
        units.append("mm")
    if params.has("gain_db"):
        parts.append(jnp.atleast_1d(ph["gain_db"] + 20 * jnp.log10(wc)))
        names.append("gain_db")
        units.append("dB")
    if params.has("phase0"):
        parts.append(jnp.atleast_1d(jnp.degrees(ph["phase0_rad"] - 2 * math.pi * spec.frequency_hz * lc)))
        names.append("phase0_deg")
        units.append("deg")
    labels = spec.raw_labels(params)
    flat = ravel_pytree(params)[0]
    coef = [i for i, lab in enumerate(labels) if "[" not in lab and lab not in OFFSET_LABELS]
    if coef:
        parts.append(flat[jnp.asarray(coef)])
        names += [labels[i] for i in coef]
        units += [coefficient_unit(labels[i]) for i in coef]
    return jnp.concatenate(parts), names, units


_quantities = small_jit(quantities)
"""`quantities` as one compiled program (called eagerly, its ~40 operations each ran as its own)."""


@small_jit
def _quantity_jacobian(spec: ModelFamily, params: FamilyParams):
    jac = jax.jacfwd(lambda p: quantities(spec, p)[0])(params)
    return _flat_jacobian(jac, params)


@small_jit
def _quantities_and_jacobian(spec: ModelFamily, params: FamilyParams):
    """(values, names, units, d values / d raw parameters) as one program (two would each be
    traced, lowered and read from the cache in every new process)."""
    v, names, units = quantities(spec, params)
    return v, names, units, _quantity_jacobian(spec, params)


def _as_solved(spec: ModelFamily, params: FamilyParams, solved_in: ModelFamily | None) -> tuple:
    """(family, parameters) to evaluate `spec`'s physics at `params` with: the richer family a fit
    was solved in (`FitResult.solved_in`) with the padded parameters where given (the same
    numbers from programs compiled for it already), else `spec` and `params`."""
    return (spec, params) if solved_in is None else (solved_in, spec.pad_params(params, solved_in))


def quantities_and_jacobian(spec: ModelFamily, params: FamilyParams, solved_in: ModelFamily | None = None) -> tuple:
    """`_quantities_and_jacobian(spec, params)` as NumPy arrays, computed in `solved_in` (a family
    `spec` nests in) where given: its rows and columns of the extra coefficients dropped."""
    fam, p = _as_solved(spec, params, solved_in)
    v, names, units, G = _quantities_and_jacobian(fam, p)
    v, G = np.asarray(v), np.asarray(G)
    if solved_in is None:
        return v, list(names), list(units), G
    keep = spec.kept_in(p, solved_in)
    extra = {lab for lab, k in zip(solved_in.raw_labels(p), keep) if not k}
    rows = [i for i, n in enumerate(names) if n not in extra]
    return (
        v[rows],
        [names[i] for i in rows],
        [units[i] for i in rows],
        G[np.ix_(np.asarray(rows, int), np.flatnonzero(keep))],
    )


def _values(spec: ModelFamily, params: FamilyParams, solved_in: ModelFamily | None = None) -> dict:
    """The quantities by name (computed in `solved_in` where given, as `quantities_and_jacobian`)."""
    if solved_in is not None:
        v, names, _, _ = quantities_and_jacobian(spec, params, solved_in)
        return dict(zip(names, v.tolist()))
    v, names, _ = _quantities(spec, params)
    return dict(zip(names, np.asarray(v).tolist()))


def _stats(r: FitResult) -> dict:
    """Statistical errors of a fit's quantities, inflated by its variance factor (its own total
    as far as the noise and its own chi2 go)."""
    v, names, _, G = _quantities_and_jacobian(r.spec, r.params)
    G = np.asarray(G)
    cov = np.asarray(r.covariance_raw)
    s = np.sqrt(np.clip(np.einsum("ij,jk,ik->i", G, cov, G), 0, None) * max(r.variance_factor, 1.0))
    return dict(zip(names, s.tolist()))


def _on_nominal(spec: ModelFamily, other_spec: ModelFamily, other: dict) -> dict:
    """Another fit's quantities (`other`: name -> number) under the nominal fit's names: per-cell
    values interpolated at the nominal cells' positions, coefficients only where the basis is the
    same."""
    out = {k: v for k, v in other.items() if not k.startswith(("w[", "lag_us[", "w.", "lag."))}
    same_basis = spec.symmetric == other_spec.symmetric and spec.n_basis == other_spec.n_basis
    for key, profile in (("w", "weights"), ("lag", "lags")):
        # a coefficient is the same quantity only in the same basis (adding a term moves the others)
        if getattr(spec, profile) == getattr(other_spec, profile) and same_basis:
            out.update({k: v for k, v in other.items() if k.startswith(f"{key}.")})
    for prefix in ("w[", "lag_us["):
        arr = [other.get(f"{prefix}{k}]") for k in range(other_spec.n_cells)]
        if arr[0] is None:
            continue
        interp = np.interp(spec.y_m, other_spec.y_m, np.asarray(arr, float))
        out.update({f"{prefix}{k}]": float(interp[k]) for k in range(spec.n_cells)})
    return out


def _per_cell(ospec: ModelFamily, p: FamilyParams, y_nom, y_other, key: str):
    """A fit's per-cell raw profile (log weight, or artanh(2 lag / T)) interpolated at `y_nom`."""
    ph = ospec.physical(p)
    v = (
        jnp.log(ph["weights_raw"])
        if key == "w"
        else jnp.arctanh(jnp.clip(2 * ph["lags_s"] / ospec.period_s, -0.999999, 0.999999))
    )
    return jnp.interp(y_nom, y_other, v)


@small_jit
def _per_cell_raw(ospec: ModelFamily, params: FamilyParams, y_nom, y_other, keys: tuple[str, ...]):
    """`_per_cell` and its Jacobian w.r.t. the raw parameters (flat) for each of `keys`, as one
    compiled program."""
    out = []
    for key in keys:
        jac = jax.jacfwd(lambda p, key=key: _per_cell(ospec, p, y_nom, y_other, key))(params)
        out.append((_per_cell(ospec, params, y_nom, y_other, key), _flat_jacobian(jac, params)))
    return tuple(out)


def _implied_coefficients(spec: ModelFamily, active: np.ndarray, other: FitResult) -> tuple[dict, dict]:
    """The nominal smooth profiles' coefficients that another family's fit implies: its per-cell
    raw profiles (log weight, artanh(2 lag / T)) interpolated at the nominal's active cells and
    projected on the nominal basis by inverse-variance weighted least squares (a free constant
    column: the gain and the offset absorb it), so cells that family determines poorly (the edge)
    count little; with the projection's statistical errors (that fit's covariance, inflated by its
    variance factor)."""
    keys = [(k, p) for k, p in (("w", spec.weights), ("lag", spec.lags)) if p == "smooth"]
    if not keys or not active.any():
        return {}, {}
    ospec, y_nom, y_other = other.spec, device_array(spec.y_m[active]), device_array(other.spec.y_m)
    cov = np.asarray(other.covariance_raw) * max(other.variance_factor, 1.0)
    vals, ses = {}, {}
    step = 2 if spec.symmetric else 1
    raws = _per_cell_raw(ospec, other.params, y_nom, y_other, tuple(k for k, _ in keys))
    for (key, profile), raw in zip(keys, raws):
        v, Gv = (np.asarray(a) for a in raw)
        cv = Gv @ cov @ Gv.T
        var = np.clip(np.diag(cv), 1e-12 * max(float(np.max(np.diag(cv))), 1e-300), None)
        E = spec.expansion(profile)[active]
        A = np.concatenate([E, np.ones((E.shape[0], 1))], axis=1)
        W = 1.0 / var
        P = np.linalg.solve(A.T @ (A * W[:, None]), (A * W[:, None]).T)[:-1]
        c = P @ v
        se = np.sqrt(np.clip(np.diag(P @ cv @ P.T), 0, None))
        for i in range(E.shape[1]):
            vals[f"{key}.T{step * (i + 1)}"] = float(c[i])
            ses[f"{key}.T{step * (i + 1)}"] = float(se[i])
    return vals, ses


def map_params(
    spec_from: ModelFamily,
    params: FamilyParams,
    spec_to: ModelFamily,
    solved_in: ModelFamily | None = None,
    *,
    physical: dict | None = None,
) -> FamilyParams:
    """A warm start for `spec_to` from a fit of `spec_from` (another resolution or family): the
    per-cell log weights and lag arguments interpolated at the new cells and projected on the new
    parameterisation (`solved_in`: the family the fit was solved in, see `_as_solved`;
    `physical`: `spec_from.physical(params)` where known, e.g. a `FitResult`'s)."""
    ph = physical if physical is not None else physical_of(*_as_solved(spec_from, params, solved_in))
    logw = np.log(np.asarray(ph["weights_raw"]))
    arg = np.arctanh(np.clip(2 * np.asarray(ph["lags_s"]) / spec_from.period_s, -0.999999, 0.999999))
    y0, y1 = spec_from.y_m, spec_to.y_m
    return spec_to.params_from_profiles(
        np.interp(y1, y0, logw), np.interp(y1, y0, arg), float(ph["diameter_m"]), params
    )
