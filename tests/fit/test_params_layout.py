"""Each family's raw parameters are a typed module (`fit.family.FamilyParams`) laid out exactly as
the dicts they replaced: `ravel_pytree` gives the same vector (values and order) and `raw_labels`
the same names, for every family and option set, so covariances, Jacobian columns, reports and
saved results keep their meaning.

The expected keys and labels below are written out from the dict-based code (a dict flattens in
sorted-key order; the keys present were: line and disc "gain_db", "phase0" always, "w" / "lag" for a
profile with parameters, "diam" when the diameter is fitted; housed: `FAMILY_PARAMS[family]` less
the fixed geometry)."""

from __future__ import annotations

import dataclasses
import math

import jax
import numpy as np
import pytest
from jax.flatten_util import ravel_pytree

from difflattice.fit.disc import DEFAULT_RIM_WIDTH_FRACTION, DiscParams, DiscSpec
from difflattice.fit.family import FamilyParams
from difflattice.fit.housed import HousedParams, HousedSpec, Housing
from difflattice.fit.model import LineParams, ModelSpec


def _logit(f: float) -> float:
    return math.log(f / (1 - f))


def _same_as_dict(p: FamilyParams, keys: list[str]):
    """The dict the old code built ({key: value}) flattens to exactly this module's vector."""
    assert list(p.names()) == sorted(keys)
    old = {k: getattr(p, k) for k in keys}  # insertion order as the old code's; jax sorts the keys
    a, b = ravel_pytree(old)[0], ravel_pytree(p)[0]
    assert a.dtype == b.dtype and a.shape == b.shape
    np.testing.assert_array_equal(np.asarray(a), np.asarray(b))
    return np.asarray(b)


LINE_CASES = [
    # (ModelSpec keywords, keys in the old dict's insertion order, labels)
    (
        {},  # smooth / smooth, 4 even terms, diameter fitted
        ["gain_db", "phase0", "w", "lag", "diam"],
        ["diameter.logit", "gain_db", *(f"lag.T{d}" for d in (2, 4, 6, 8)), "phase0_rad"]
        + [f"w.T{d}" for d in (2, 4, 6, 8)],
    ),
    (
        {"weights": "free", "lags": "symmetric", "fit_diameter": False, "diameter_m": 4e-3},
        ["gain_db", "phase0", "w", "lag"],
        ["gain_db", "lag[0|4]", "lag[1|3]", "phase0_rad", "w[0]", "w[1]", "w[3]", "w[4]"],
    ),
    (
        {"weights": "uniform", "lags": "smooth", "symmetric": False, "n_basis": 2},
        ["gain_db", "phase0", "lag", "diam"],
        ["diameter.logit", "gain_db", "lag.T1", "lag.T2", "phase0_rad"],
    ),
    (
        {"weights": "symmetric", "lags": "uniform"},
        ["gain_db", "phase0", "w", "diam"],
        ["diameter.logit", "gain_db", "phase0_rad", "w[0|4]", "w[1|3]"],
    ),
]


@pytest.mark.parametrize("kw,keys,labels", LINE_CASES)
def test_line_parameters_flatten_as_the_dict(kw, keys, labels):
    spec = ModelSpec(n_cells=5, dx_m=1e-3, frequency_hz=50e3, **kw)
    p = spec.init_params()
    assert isinstance(p, LineParams)
    flat = _same_as_dict(p, keys)
    assert spec.raw_labels(p) == labels
    expect = {lab: 0.0 for lab in labels}
    if spec.fit_diameter:
        expect["diameter.logit"] = _logit(0.97)
    np.testing.assert_array_equal(flat, [expect[lab] for lab in labels])


DISC_CASES = [
    ({}, ["gain_db", "phase0", "diam"], ["diameter.logit", "gain_db", "phase0_rad"]),
    (
        {"weights": "rim_taper", "lags": "smooth", "n_basis": 2},
        ["gain_db", "phase0", "w", "lag", "diam"],
        ["diameter.logit", "gain_db", "lag.T2", "lag.T4", "phase0_rad", "w.rim_log", "w.rim_width_logit"],
    ),
    (
        {"weights": "free", "lags": "rim_taper", "rim_width_m": 1e-3, "fit_diameter": False, "diameter_m": 6e-3},
        ["gain_db", "phase0", "w", "lag"],
        ["gain_db", "lag.rim_atanh", "phase0_rad", "w[1]", "w[2]", "w[3]"],
    ),
]


@pytest.mark.parametrize("kw,keys,labels", DISC_CASES)
def test_disc_parameters_flatten_as_the_dict(kw, keys, labels):
    spec = DiscSpec(n_cells=4, dx_m=1e-3, frequency_hz=50e3, **kw)
    p = spec.init_params()
    assert isinstance(p, DiscParams)
    flat = _same_as_dict(p, keys)
    assert spec.raw_labels(p) == labels
    expect = {lab: 0.0 for lab in labels}
    if spec.fit_diameter:
        expect["diameter.logit"] = _logit(0.97)
    if "w.rim_width_logit" in expect:
        expect["w.rim_width_logit"] = _logit(DEFAULT_RIM_WIDTH_FRACTION)
    np.testing.assert_allclose(flat, [expect[lab] for lab in labels], rtol=1e-15, atol=0)


HOUSED_CASES = [
    ("flat", (), ["diam", "gain_db"]),
    ("recessed", (), ["diam", "recess", "gain_db"]),
    ("opening", (), ["diam", "recess", "opening", "gain_db"]),
    ("opening", ("opening",), ["diam", "recess", "gain_db"]),
    ("recessed", ("diaphragm", "recess"), ["gain_db"]),
    ("profile", (), ["diam", "gain_db", "w", "lag"]),
]


@pytest.mark.parametrize("family,fixed,keys", HOUSED_CASES)
def test_housed_parameters_flatten_as_the_dict(family, fixed, keys):
    h = Housing(outer_diameter_m=16e-3, length_m=10e-3, plate_m=1.8e-3)
    spec = HousedSpec(
        housing=h,
        frequency_hz=40e3,
        cells_per_wavelength=10,
        family=family,
        fixed=fixed,
        diaphragm_m=9e-3,
        recess_m=2e-3,
        opening_m=11e-3,
    )
    p = spec.init_params()
    assert isinstance(p, HousedParams)
    flat = _same_as_dict(p, keys)
    n_rings_1 = spec.n_rings - 1
    assert flat.size == len(keys) + (2 * (n_rings_1 - 1) if family == "profile" else 0)
    # a start written by replace keeps the layout and moves only its own entry
    q = dataclasses.replace(p, gain_db=p.gain_db + 1.0)
    at = sum(np.size(getattr(p, k)) for k in p.names() if k < "gain_db")
    np.testing.assert_array_equal(np.asarray(ravel_pytree(q)[0]) - flat, np.eye(flat.size)[at])


@pytest.mark.parametrize("cls", [LineParams, DiscParams, HousedParams])
def test_fields_are_declared_in_name_order(cls):
    """The invariant that makes a module flatten like the dict: fields in alphabetical order."""
    names = [f.name for f in dataclasses.fields(cls)]
    assert names == sorted(names)


def test_optional_parameters_are_none_and_absent_from_the_vector():
    spec = ModelSpec(n_cells=5, dx_m=1e-3, frequency_hz=50e3, weights="uniform", lags="uniform", fit_diameter=False)
    p = spec.init_params()
    assert p.w is None and p.lag is None and p.diam is None and p.names() == ("gain_db", "phase0")
    assert p.without("phase0").names() == ("gain_db",) and not p.without("phase0").has("phase0")
    full = ModelSpec(n_cells=5, dx_m=1e-3, frequency_hz=50e3).init_params()
    held = full.only(["w", "lag"])
    assert held.names() == ("lag", "w")
    merged = full.without("w", "lag").merged(held)
    assert jax.tree_util.tree_structure(merged) == jax.tree_util.tree_structure(full)
    np.testing.assert_array_equal(np.asarray(ravel_pytree(merged)[0]), np.asarray(ravel_pytree(full)[0]))


def test_a_dict_start_is_refused_by_name():
    from difflattice.fit.solve import _check_params

    spec = ModelSpec(n_cells=5, dx_m=1e-3, frequency_hz=50e3)
    _check_params(spec, spec.init_params(), "params0")
    with pytest.raises(TypeError, match=r"params0 is a dict; give the family's parameter module \(LineParams\)"):
        _check_params(spec, {"diam": 0.0}, "params0")
