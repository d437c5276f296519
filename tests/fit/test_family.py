"""The model-family interface (`fit.family.ModelFamily`): the shipped families implement all of it,
and a family that leaves a method out cannot be made (an error naming it, not a failure deep in a fit)."""

import dataclasses

import jax
import pytest

from difflattice.fit.disc import DiscSpec
from difflattice.fit.family import ModelFamily
from difflattice.fit.model import ModelSpec


@pytest.mark.parametrize("cls", [ModelSpec, DiscSpec])
def test_shipped_families_implement_the_interface(cls):
    spec = cls(n_cells=12, dx_m=1e-3, frequency_hz=50e3)
    assert isinstance(spec, ModelFamily) and spec.kind in ("line", "disc")
    assert not getattr(cls, "__abstractmethods__", None)
    p = spec.init_params()
    ph = spec.physical(p)
    assert {"weights", "lags_s", "diameter_m", "gain_db", "phase0_rad"} <= set(ph)
    assert spec.amplitudes(p).shape == (spec.n_cells,)
    assert len(spec.raw_labels(p)) == sum(v.size for v in jax.tree_util.tree_leaves(p))
    # a refit at another resolution is a replace of the shared fields
    assert dataclasses.replace(spec, n_cells=16, dx_m=0.75e-3).d_max_m == pytest.approx(spec.d_max_m, rel=1e-12)


def test_a_family_missing_a_method_cannot_be_made():
    @dataclasses.dataclass(frozen=True)
    class Incomplete(ModelFamily):
        n_cells: int = 4

    with pytest.raises(TypeError, match="abstract"):
        Incomplete()
