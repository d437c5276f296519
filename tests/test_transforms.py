"""The host-side parameter maps: logit and sigmoid are inverses, agree with independent formulas
and JAX's sigmoid, and refuse fractions with no finite raw value."""

import math

import jax
import numpy as np
import pytest

from difflattice.transforms import logit, sigmoid


@pytest.mark.parametrize("f", [1e-6, 1e-3, 0.15, 0.5, 0.97, 1 - 1e-6])
def test_logit_inverts_sigmoid_and_matches_references(f):
    u = logit(f)
    assert u == pytest.approx(math.log(f) - math.log1p(-f), rel=1e-12, abs=1e-15)
    # the round trip loses at most the conditioning of log(f / (1 - f)): ~1e-16 / (1 - f)
    assert sigmoid(u) == pytest.approx(f, rel=4e-16 / (1 - f) + 1e-15)
    assert sigmoid(u) == pytest.approx(float(jax.nn.sigmoid(np.float64(u))), rel=1e-12)


def test_sigmoid_extremes_do_not_overflow():
    assert sigmoid(-1000.0) == 0.0 and sigmoid(1000.0) == 1.0
    assert sigmoid(0.0) == 0.5 and logit(0.5) == 0.0


@pytest.mark.parametrize("f", [0.0, 1.0, -0.1, 1.5, float("nan")])
def test_logit_refuses_fractions_outside_the_open_interval(f):
    with pytest.raises(ValueError, match="strictly between 0 and 1"):
        logit(f)
