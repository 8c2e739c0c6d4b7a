"""numpy <-> GTSAM helpers: poses, keys, tangent conventions and GTSAM's error messages.

GTSAM's ``Pose3`` is perturbed on the right with the rotation first (``[w; v]``); the
:class:`ekf.estimate.Estimate` convention is the right perturbation with the translation first.
The permutation between them lives in :mod:`ekf.conventions` (``ESTIMATE_TO_GTSAM``); this
module only adds what needs gtsam itself.
"""

from __future__ import annotations

import re

import gtsam
import numpy as np
from gtsam.symbol_shorthand import L, X

from vislam.ekf.conventions import ESTIMATE_TO_GTSAM
from vislam.ekf.errors import EstimationError

__all__ = [
    "L",
    "X",
    "to_pose3",
    "from_pose3",
    "twist_to_gtsam",
    "expmap_right_jacobian",
    "key_name",
    "estimation_error",
    "named_error",
]

#: What the key characters stand for, in error messages.
_KEY_KINDS = {"x": "pose", "l": "landmark"}


def to_pose3(T: np.ndarray) -> gtsam.Pose3:
    """A 4x4 rigid transform as a ``gtsam.Pose3``."""
    return gtsam.Pose3(np.asarray(T, dtype=float))


def from_pose3(pose: gtsam.Pose3) -> np.ndarray:
    """A ``gtsam.Pose3`` as a 4x4 array."""
    return np.asarray(pose.matrix(), dtype=float)


def twist_to_gtsam(xi: np.ndarray) -> np.ndarray:
    """Translation-first twist(s) ``[rho; phi]`` (..., 6) -> GTSAM's ``[phi; rho]``."""
    return np.asarray(xi, dtype=float) @ ESTIMATE_TO_GTSAM.T


def expmap_right_jacobian(xi_gtsam: np.ndarray) -> np.ndarray:
    """Right Jacobian of ``Pose3.Expmap`` at a rotation-first twist (6x6, rotation first):
    ``Expmap(xi + d) ~= Expmap(xi) * Expmap(J d)``."""
    return np.asarray(gtsam.Pose3.ExpmapDerivative(np.asarray(xi_gtsam, dtype=float)))


def interval_jacobians(twist: np.ndarray, tau: np.ndarray) -> np.ndarray:
    """``tau_k J_r(tau_k u_k)`` (n, 6, 6), GTSAM order: how a twist error ``w`` (rotation first)
    of interval k moves its relative motion, ``exp(tau (u + w)) ~= exp(tau u) Exp(tau J_r w)``.
    ``twist`` (n, 6) translation first, ``tau`` (n,) seconds."""
    tau = np.asarray(tau, dtype=float)
    xi_g = twist_to_gtsam(tau[:, None] * np.asarray(twist, dtype=float).reshape(-1, 6))
    out = np.empty((len(tau), 6, 6))
    for k in range(len(tau)):
        out[k] = tau[k] * expmap_right_jacobian(xi_g[k])
    return out


def key_name(key: int) -> str:
    """``'pose x12'`` / ``'landmark l345'`` for a key made with :data:`X` / :data:`L`."""
    symbol = gtsam.Symbol(int(key))
    char = chr(symbol.chr())
    kind = _KEY_KINDS.get(char, "variable")
    return f"{kind} {char}{symbol.index()}"


_SYMBOL_IN_MESSAGE = re.compile(r"Symbol:\s*([A-Za-z])(\d+)")
_KEY_IN_MESSAGE = re.compile(r"variable\s+(\d{6,})")


def estimation_error(exc: BaseException, stage: str, names: dict[str, str] | None = None,
                     estimator: str = "smoother") -> EstimationError:
    """Turn an exception raised inside GTSAM into an :class:`EstimationError` naming the variable.

    GTSAM's messages carry the key as an integer and usually as ``(Symbol: l12)``; both are
    decoded to ``'landmark l12'``. ``names`` may map ``'l12'`` to extra context (e.g. the source
    track). ``stage`` says what was being done ("optimising", "computing marginals");
    ``estimator`` starts the message (``"smoother"`` or ``"smoother-isam2"``).
    """
    text = str(exc)
    variable = None
    match = _SYMBOL_IN_MESSAGE.search(text)
    if match:
        char, index = match.group(1), int(match.group(2))
        variable = f"{_KEY_KINDS.get(char, 'variable')} {char}{index}"
    else:
        match = _KEY_IN_MESSAGE.search(text)
        if match:
            variable = key_name(int(match.group(1)))
    first_line = " ".join(line.strip() for line in text.strip().splitlines()[:1]) or type(exc).__name__
    if "Indetermina" in text:
        reason = "the linear system is indeterminate (an under-constrained or degenerate variable)"
    else:
        reason = first_line
    if variable is None:
        return EstimationError(f"{estimator} failed while {stage}: {reason}")
    short = variable.split()[-1]
    extra = f" ({names[short]})" if names and short in names else ""
    return EstimationError(f"{estimator} failed while {stage} near {variable}{extra}: {reason}")


def named_error(exc: EstimationError, estimator: str) -> EstimationError:
    """``exc`` with its message starting with the estimator's name (errors raised by shared
    parts, e.g. the marginals or an EKF initialisation, name only what failed)."""
    text = " ".join(str(exc).split("\n"))
    if text.startswith(f"{estimator}:") or text.startswith(f"{estimator} "):
        return exc if "\n" not in str(exc) else EstimationError(text)
    return EstimationError(f"{estimator}: {text}")
