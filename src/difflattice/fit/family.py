"""The interface every transducer model family implements, so that the solve (`fit.solve`), the
error budget (`fit.uncertainty`) and the reports run any family unchanged.

A family is a frozen dataclass of static configuration (what is fitted and how) whose methods map
the raw, unconstrained parameters (the differentiable part: a frozen `FamilyParams` module of the
family's own, returned by `init_params`) to the source cells' complex amplitudes and to physical
quantities. Final families: `fit.model.ModelSpec` (a line of cells on the 2-D lattice, "line",
parameters `fit.model.LineParams`) and `fit.disc.DiscSpec` (rings of a disc on the axisymmetric
lattice, "disc", parameters `fit.disc.DiscParams`); the housed family `fit.housed.HousedSpec`
(its own lattice fit, `fit.ladder`) has `fit.housed.HousedParams`. A new family is one file with
one such class and its parameter module, its transfer (the observables' linear map from the
amplitudes) and one entry in `apps.fitting`'s table of family set-ups.
"""

from __future__ import annotations

import abc
import dataclasses
from collections.abc import Callable, Iterable
from typing import Any, ClassVar, Generic, Self, TypeVar, cast

import equinox as eqx
import jax
import numpy as np


class FamilyParams(eqx.Module):
    """A model family's raw (unconstrained) parameters: the differentiable part of a fit, a frozen
    module whose fields are arrays, or None for a parameter the fit does not have (a diameter held
    at its value, an offset no data see, a uniform profile).

    Subclasses declare their fields in alphabetical order: `jax.flatten_util.ravel_pytree` then
    orders the raw parameter vector (covariances, Jacobian columns, `raw_labels`, reports) by name,
    as it did when the parameters were a dict. Update by `dataclasses.replace` (or `without`)."""

    def names(self) -> tuple[str, ...]:
        """The parameters present (not None), in `ravel_pytree` order."""
        return tuple(f.name for f in dataclasses.fields(self) if getattr(self, f.name) is not None)

    def has(self, name: str) -> bool:
        """Whether the parameter `name` is fitted (present, not None)."""
        return getattr(self, name, None) is not None

    def without(self, *names: str) -> Self:
        """These parameters with `names` removed (None)."""
        return dataclasses.replace(self, **{n: None for n in names})

    def only(self, names: Iterable[str]) -> Self:
        """These parameters with every one not in `names` removed (None)."""
        keep = set(names)
        return self.without(*(n for n in self.names() if n not in keep))

    def merged(self, over: FamilyParams | None) -> Self:
        """These parameters with those present in `over` (same class) taking their place."""
        return self if over is None else cast(Self, eqx.combine(over, self, is_leaf=lambda x: x is None))

    def replace(self, **values: Any) -> Self:
        """`dataclasses.replace` for code that holds any family's parameters (the field names
        are checked at run time: a name the family does not have is a TypeError)."""
        return dataclasses.replace(self, **values)


P = TypeVar("P", bound=FamilyParams)
"""A family's parameter module."""


class ModelFamily(abc.ABC, Generic[P]):
    """A transducer model family (abstract). Subclasses are frozen dataclasses with at least the
    fields `n_cells` (source cells or rings), `dx_m` (their pitch, m), `frequency_hz`, `weights`
    and `lags` (profile names), `n_basis`, `fit_diameter` and `diameter_m`, so that a refit at
    another resolution is `dataclasses.replace(spec, n_cells=..., dx_m=...)`."""

    kind: ClassVar[str]
    """The family's name in configs and reports ("line", "disc")."""
    __dataclass_fields__: ClassVar[dict[str, dataclasses.Field[Any]]]
    """Every family is a dataclass (so `dataclasses.replace` applies to any family)."""

    n_cells: int
    dx_m: float
    frequency_hz: float
    weights: str
    lags: str
    n_basis: int
    symmetric: bool
    fit_diameter: bool
    diameter_m: float | None

    # -- geometry -------------------------------------------------------------------------
    @property
    @abc.abstractmethod
    def y_m(self) -> np.ndarray:
        """Cell (or ring-centre) positions across the face, m."""

    @property
    @abc.abstractmethod
    def d_max_m(self) -> float:
        """The modelled face's size (the diameter's upper bound), m."""

    @property
    @abc.abstractmethod
    def edge_softness_m(self) -> float:
        """Width scale of the aperture's edge, m (resolution independent)."""

    @property
    def period_s(self) -> float:
        """The drive period, s."""
        return 1.0 / self.frequency_hz

    @property
    @abc.abstractmethod
    def reference_cells(self) -> tuple[int, ...]:
        """The cell(s) profiles are referred to (relative weights and lags)."""

    # -- parameters -----------------------------------------------------------------------
    @abc.abstractmethod
    def init_params(self) -> P:
        """The initial raw parameters (uniform face, no lags, the initial diameter)."""

    @abc.abstractmethod
    def physical(self, params: P) -> dict:
        """Physical quantities: `weights` (aperture applied), `weights_raw`, `lags_s`, `diameter_m`,
        `gain_db`, `phase0_rad`."""

    @abc.abstractmethod
    def amplitudes(self, params: P):
        """The cells' complex amplitudes w exp(i omega tau) (times the gain and offset)."""

    @abc.abstractmethod
    def raw_labels(self, params: P) -> list[str]:
        """A name per raw parameter, in `ravel_pytree` order."""

    @abc.abstractmethod
    def bounds(self) -> dict:
        """Physical bounds: `diameter_mm` (lo, hi) and `lag_us` (lo, hi)."""

    @abc.abstractmethod
    def expansion(self, profile: str) -> np.ndarray:
        """(n_cells, n_coefficients) map from a smooth profile's coefficients to per-cell values."""

    @abc.abstractmethod
    def params_from_profiles(self, log_weights, lag_args, diameter_m: float | None, template: FamilyParams) -> P:
        """Raw parameters that reproduce per-cell profiles (a warm start from another model)."""

    @abc.abstractmethod
    def symmetries(self) -> dict[str, Callable[[P], P]]:
        """Candidate symmetries of the data under this model: name -> map of the raw parameters
        (the error budget refits from each image to decide identifiability)."""

    # -- nesting: solving in a richer family (shared compiled programs) ----------------------
    def nests_in(self, other: ModelFamily) -> bool:
        """Whether `other` is this family with more basis functions for its smooth profile(s), so
        that these parameters are `other`'s with the extra coefficients at zero (both families'
        smooth bases are the first `n_basis` functions of one sequence)."""
        return (
            type(other) is type(self)
            and "smooth" in (self.weights, self.lags)
            and other.n_basis > self.n_basis
            and dataclasses.replace(self, n_basis=other.n_basis) == other
        )

    def _padded_keys(self) -> tuple[str, ...]:
        return tuple(k for k, profile in (("w", self.weights), ("lag", self.lags)) if profile == "smooth")

    def pad_params(self, params: P, other: ModelFamily) -> FamilyParams:
        """These parameters as `other`'s (a family this one `nests_in`): the extra coefficients 0."""
        extra = other.n_basis - self.n_basis
        # on the host (eager jnp operations would each be a program of their own in a new process)
        pad = {}
        for k in self._padded_keys():
            if params.has(k):
                v = np.asarray(getattr(params, k))
                pad[k] = jax.device_put(np.concatenate([v, np.zeros(extra, v.dtype)]))
        return params.replace(**pad)

    def unpad_params(self, params: FamilyParams, other: ModelFamily) -> P:
        """`other`'s parameters (extra coefficients at zero) as this family's: the inverse of
        `pad_params`."""
        cut = {
            k: jax.device_put(np.asarray(getattr(params, k))[: self.n_basis])
            for k in self._padded_keys()
            if params.has(k)
        }
        return cast(P, params.replace(**cut))

    def kept_in(self, params: FamilyParams, other: ModelFamily) -> np.ndarray:
        """(n,) bool over `params`, raw parameters of `other` (a family this one `nests_in`) in
        `ravel_pytree` order: True for this family's, False for the extra coefficients."""
        extra = other.n_basis - self.n_basis
        padded = self._padded_keys()
        out: list[bool] = []
        for k in params.names():
            n = int(np.size(getattr(params, k)))
            out += [True] * (n - extra) + [False] * extra if k in padded else [True] * n
        return np.asarray(out, bool)
