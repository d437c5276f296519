"""The two distribution functions the fit's p-values need, without scipy.stats (whose import is
~1 s of a fresh fit's start-up): the chi-square survival function and the normal distribution
function."""

from __future__ import annotations

import math


def chi2_sf(x: float, dof: float) -> float:
    """P(chi2 >= x) for `dof` degrees of freedom: the regularised upper incomplete gamma function
    Q(dof / 2, x / 2) (scipy.special, not scipy.stats: the fit's start-up pays ~0.1 s for it, not
    ~1 s for scipy.stats' distribution machinery)."""
    from scipy.special import gammaincc

    return float(gammaincc(0.5 * dof, 0.5 * max(x, 0.0)))


def normal_cdf(z: float) -> float:
    """The standard normal distribution function."""
    return 0.5 * math.erfc(-z / math.sqrt(2.0))
