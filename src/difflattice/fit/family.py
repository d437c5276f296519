"""The interface every transducer model family implements, so that the solve (`fit.solve`), the
error budget (`fit.uncertainty`) and the reports run any family unchanged.

A family is a frozen dataclass of static configuration (what is fitted and how) whose methods map
the raw, unconstrained parameters (a dict of arrays: the differentiable part) to the source cells'
complex amplitudes and to physical quantities. Final families: `fit.model.ModelSpec` (a line of
cells on the 2-D lattice, "line") and `fit.disc.DiscSpec` (rings of a disc on the axisymmetric
lattice, "disc"). A new family is one file with one such class, its transfer (the observables'
linear map from the amplitudes) and one entry in `apps.fitting`'s table of family set-ups.
"""

from __future__ import annotations

import abc
from collections.abc import Callable
from typing import ClassVar

import numpy as np


class ModelFamily(abc.ABC):
    """A transducer model family (abstract). Subclasses are frozen dataclasses with at least the
    fields `n_cells` (source cells or rings), `dx_m` (their pitch, m), `frequency_hz`, `weights`
    and `lags` (profile names), `n_basis`, `fit_diameter` and `diameter_m`, so that a refit at
    another resolution is `dataclasses.replace(spec, n_cells=..., dx_m=...)`."""

    kind: ClassVar[str]
    """The family's name in configs and reports ("line", "disc")."""

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
    def init_params(self) -> dict:
        """The initial raw parameters (uniform face, no lags, the initial diameter)."""

    @abc.abstractmethod
    def physical(self, params: dict) -> dict:
        """Physical quantities: `weights` (aperture applied), `weights_raw`, `lags_s`, `diameter_m`,
        `gain_db`, `phase0_rad`."""

    @abc.abstractmethod
    def amplitudes(self, params: dict):
        """The cells' complex amplitudes w exp(i omega tau) (times the gain and offset)."""

    @abc.abstractmethod
    def raw_labels(self, params: dict) -> list[str]:
        """A name per raw parameter, in `ravel_pytree` order."""

    @abc.abstractmethod
    def bounds(self) -> dict:
        """Physical bounds: `diameter_mm` (lo, hi) and `lag_us` (lo, hi)."""

    @abc.abstractmethod
    def expansion(self, profile: str) -> np.ndarray:
        """(n_cells, n_coefficients) map from a smooth profile's coefficients to per-cell values."""

    @abc.abstractmethod
    def params_from_profiles(self, log_weights, lag_args, diameter_m: float | None, template: dict) -> dict:
        """Raw parameters that reproduce per-cell profiles (a warm start from another model)."""

    @abc.abstractmethod
    def symmetries(self) -> dict[str, Callable[[dict], dict]]:
        """Candidate symmetries of the data under this model: name -> map of the raw parameters
        (the error budget refits from each image to decide identifiability)."""
