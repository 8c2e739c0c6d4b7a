"""The chi-square distribution's quantile, distribution and survival functions, as
``scipy.stats.chi2`` computes them (the same special functions, so the same numbers to the bit:
tests/test_chi_square.py), from ``scipy.special`` alone: importing ``scipy.stats`` took about
1.2 s of every vislam command's start, for these three functions of the gates, bounds and tests.

    ppf(p, k) = 2 P^-1(k/2, p)      (P: the regularised lower incomplete gamma function)
    cdf(x, k) = P(k/2, x/2),  sf(x, k) = Q(k/2, x/2) = 1 - cdf(x, k)   (0 and 1 for x <= 0)
"""

from __future__ import annotations

import numpy as np
from scipy import special


def ppf(p, dof):
    """The ``p`` quantile of chi-square with ``dof`` degrees of freedom (0 at p = 0, inf at 1)."""
    return 2 * special.gammaincinv(np.asarray(dof, dtype=float) / 2, p)


def cdf(x, dof):
    """P(X <= x) for X chi-square with ``dof`` degrees of freedom."""
    return special.chdtr(dof, np.maximum(x, 0.0))


def sf(x, dof):
    """P(X > x) for X chi-square with ``dof`` degrees of freedom."""
    return special.chdtrc(dof, np.maximum(x, 0.0))


__all__ = ["cdf", "ppf", "sf"]
