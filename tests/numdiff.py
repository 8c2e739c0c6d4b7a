"""Central finite differences for checking analytic Jacobians in the tests."""

import numpy as np


def numeric_jacobian(f, x, eps=1e-6):
    """d f / d x at ``x`` by central differences; f may return any array shape."""
    x = np.asarray(x, dtype=float)
    f0 = np.asarray(f(x))
    J = np.zeros(f0.shape + x.shape)
    for i in range(x.size):
        dx = np.zeros_like(x)
        dx.flat[i] = eps
        J[..., i] = (np.asarray(f(x + dx)) - np.asarray(f(x - dx))) / (2 * eps)
    return J
