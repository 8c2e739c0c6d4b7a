"""ekf.chi_square gives scipy.stats.chi2's numbers to the bit, edge cases included."""

import numpy as np
import pytest
from scipy.stats import chi2

from vislam.ekf import chi_square

DOFS = [1, 3, 4, 6, 7.5, 18, 600, 7200]


@pytest.mark.parametrize("dof", DOFS)
def test_quantiles_are_scipy_stats(dof):
    p = np.array([0.0, 1e-12, 0.0013, 0.025, 0.5, 0.95, 0.975, 0.99, 0.9973, 1 - 1e-9, 1.0])
    assert np.array_equal(chi_square.ppf(p, dof), chi2.ppf(p, dof))
    for q in p:
        assert chi_square.ppf(q, dof) == chi2.ppf(q, dof)


@pytest.mark.parametrize("dof", DOFS)
def test_distribution_and_survival_are_scipy_stats(dof):
    x = np.array([-np.inf, -1.0, 0.0, 1e-300, 0.5, 9.0, 12.6, 1e3, 1e6, np.inf, np.nan])
    assert np.array_equal(chi_square.cdf(x, dof), chi2.cdf(x, dof), equal_nan=True)
    assert np.array_equal(chi_square.sf(x, dof), chi2.sf(x, dof), equal_nan=True)
    assert chi_square.cdf(9.0, dof) == chi2.cdf(9.0, dof)
