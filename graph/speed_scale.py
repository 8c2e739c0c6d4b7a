"""A slowly varying speed scale of the linear velocities, carried as variables of the batch smoother.

A drive's linear velocities may be off by a slowly varying factor, ``v_true = (1 + s) v`` (wheel
radius, a GPS/IMU's slow errors; ``FilterConfig.speed_scale``). Modelled as white velocity
noise it has to be inflated until it swamps the velocities' short-term precision; as a state it
costs one scalar per interval. The EKFs carry ``s`` as a random walk (``ekf.prediction``,
``twist_error_matrix``); the smoother does the same with one variable ``S(i)`` per interval:

* a prior ``s_0 ~ N(0, speed_scale_sigma^2)`` on the first,
* between consecutive ones ``s_{k+1} - s_k ~ N(0, speed_scale_walk^2 (tau_k + tau_{k+1}) / 2)``
  (the time between the intervals' midpoints),
* with ``speed_scale_walk == 0`` (a constant scale) one variable ``S(0)`` shared by every interval.

Motion factor on ``x_k``, ``x_{k+1}``, ``s`` (and the gyro bias ``b`` when the graph has one,
``gyro_bias="joint"``). In GTSAM's rotation-first order the interval's twist is
``xi(s) = tau [w; (1 + s) v] = xi_0 + s dxi`` with ``dxi = tau [0; v]``, and the measured motion

    P(s, b) = Exp(xi(s)) C(b),    C(b) = Exp(-D_k b)  (graph.gyro_bias; a fixed ``C`` when the
                                                        bias was removed beforehand, "alternate")

is exact in ``s`` (the twist is scaled before the exponential). The error is that of the plain
between-factor, ``e = Log(P^-1 x_k^-1 x_{k+1})``, with the plain factor's covariance. With
``R = P^-1 B``, ``B = x_k^-1 x_{k+1}`` and ``J_r`` = ``Pose3.ExpmapDerivative``,
``J_r^-1(e)`` = ``Pose3.LogmapDerivative(e)``:

    de/dx_k     = -J_r^-1(e) Ad(B^-1)
    de/dx_{k+1} =  J_r^-1(e)
    de/ds       = -J_r^-1(e) Ad(R^-1) Ad(C^-1) J_r(xi(s)) dxi
    de/db       =  J_r^-1(e) Ad(R^-1) J_r(-D_k b) D_k

(``Exp(xi + dxi ds) = Exp(xi) Exp(J_r(xi) dxi ds)``, moved through ``C`` by its adjoint; the
bias term is graph.gyro_bias's). Tested against numerical derivatives in
tests/test_graph_speed_scale.py. Each factor is a ``gtsam.CustomFactor`` (a Python callback), one
per interval, like the joint gyro bias.
"""

from __future__ import annotations

from dataclasses import dataclass

import gtsam
import numpy as np
from gtsam.symbol_shorthand import S

from vislam.graph.gyro_bias import relative_motion_error
from vislam.graph.pose_conversions import to_pose3, twist_to_gtsam

__all__ = ["S", "SpeedScaleModel", "scaled_motion_error", "scaled_motion_factor", "scaled_deltas",
           "scale_values"]


def scaled_motion_error(xi0: np.ndarray, dxi: np.ndarray, x0: gtsam.Pose3, x1: gtsam.Pose3,
                        s: float, correction: gtsam.Pose3 | None = None,
                        D: np.ndarray | None = None, bias: np.ndarray | None = None,
                        H: list | None = None) -> np.ndarray:
    """The factor's error (6,) (module docstring) and, when ``H`` is a list, its Jacobians
    appended to it: wrt ``x0``, ``x1``, ``s`` (6x6, 6x6, 6x1) and, with ``bias``, wrt the bias
    (6x3). ``correction`` a fixed ``C`` (ignored with ``bias``: then ``C = Exp(-D b)``)."""
    xi = xi0 + s * dxi
    A = gtsam.Pose3.Expmap(xi)
    Db = None
    if bias is not None:
        Db = D @ np.asarray(bias, dtype=float)
        C = gtsam.Pose3.Expmap(-Db)
    else:
        C = correction
    P = A if C is None else A.compose(C)
    e, R, J_log = relative_motion_error(P, x0, x1, H)
    if H is not None:
        CR_inv = R.inverse().AdjointMap() if C is None else C.compose(R).inverse().AdjointMap()
        H.append((-J_log @ CR_inv @ gtsam.Pose3.ExpmapDerivative(xi) @ dxi)[:, None])
        if bias is not None:
            H.append(J_log @ R.inverse().AdjointMap() @ gtsam.Pose3.ExpmapDerivative(-Db) @ D)
    return e


def scaled_motion_factor(k0: int, k1: int, scale_key: int, xi0: np.ndarray, dxi: np.ndarray,
                         noise: gtsam.noiseModel.Base, correction: np.ndarray | None = None,
                         bias_key: int | None = None, D: np.ndarray | None = None) -> gtsam.CustomFactor:
    """A ``CustomFactor`` on (``k0``, ``k1``, ``scale_key``) (and ``bias_key`` with its bias
    Jacobian ``D`` (6x3)) for the interval twist ``xi0`` (rotation first, times tau), its
    derivative in the scale ``dxi`` and the fixed correction ``correction`` (4x4, or None)."""
    xi0 = np.ascontiguousarray(xi0, dtype=float)
    dxi = np.ascontiguousarray(dxi, dtype=float)
    C = None if correction is None else to_pose3(correction)
    keys = [int(k0), int(k1), int(scale_key)]
    if bias_key is not None:
        keys.append(int(bias_key))
        D = np.ascontiguousarray(D, dtype=float)

    def error(this: gtsam.CustomFactor, values: gtsam.Values, jacobians) -> np.ndarray:
        k = this.keys()
        x0 = values.atPose3(k[0])
        x1 = values.atPose3(k[1])
        s = values.atDouble(k[2])
        b = values.atPoint3(k[3]) if bias_key is not None else None
        if jacobians is None:
            return scaled_motion_error(xi0, dxi, x0, x1, s, C, D, b)
        H: list = []
        e = scaled_motion_error(xi0, dxi, x0, x1, s, C, D, b, H)
        for i, J in enumerate(H):
            jacobians[i] = J
        return e

    return gtsam.CustomFactor(noise, keys, error)


def scaled_deltas(twists: np.ndarray, tau: np.ndarray, scale: np.ndarray,
                  corrections: np.ndarray | None = None) -> np.ndarray:
    """The relative motions ``Exp(tau [w; (1 + s_k) v]) C_k`` (T-1, 4, 4) for per-interval
    scales ``scale`` (T-1,) and fixed corrections ``corrections`` (T-1, 4, 4) or None."""
    xi = twist_to_gtsam(np.asarray(tau, dtype=float)[:, None] * np.asarray(twists, dtype=float))
    out = np.empty((len(xi), 4, 4))
    for k in range(len(xi)):
        dxi = np.r_[np.zeros(3), xi[k, 3:]]
        P = gtsam.Pose3.Expmap(xi[k] + scale[k] * dxi)
        if corrections is not None:
            P = P.compose(to_pose3(corrections[k]))
        out[k] = P.matrix()
    return out


@dataclass
class SpeedScaleModel:
    """What the graph needs to estimate the speed scale (module docstring): per interval its
    twist ``xi0`` (T-1, 6) and scale derivative ``dxi`` (T-1, 6) (rotation first, times tau),
    the variable it uses ``index`` (T-1,), the prior on the first variable, the random walk
    between consecutive ones (one noise model each; empty for a constant scale), the initial
    values (n,) and the fixed corrections of the motions (T-1, 4, 4: the gyro bias removed
    beforehand, ``"alternate"``) or None."""

    twists: np.ndarray
    tau: np.ndarray
    xi0: np.ndarray
    dxi: np.ndarray
    index: np.ndarray
    prior: gtsam.noiseModel.Base
    walk: list
    initial: np.ndarray
    corrections: np.ndarray | None = None

    @classmethod
    def create(cls, twists: np.ndarray, tau: np.ndarray, sigma: float, walk: float,
               initial: np.ndarray | None = None) -> "SpeedScaleModel":
        """``twists`` (T-1, 6) translation first, ``tau`` (T-1,) seconds; ``sigma`` the prior's
        1-sd of the first scale, ``walk`` the random walk (relative/sqrt(s); 0: one constant)."""
        twists = np.asarray(twists, dtype=float)
        tau = np.asarray(tau, dtype=float)
        n = len(tau)
        xi0 = twist_to_gtsam(tau[:, None] * twists) if n else np.zeros((0, 6))
        dxi = np.zeros_like(xi0)
        dxi[:, 3:] = xi0[:, 3:]
        if walk > 0.0:
            index = np.arange(n)
            gaps = 0.5 * (tau[:-1] + tau[1:])
            # a zero-length gap would give a zero sigma: keep it barely positive
            walks = [gtsam.noiseModel.Isotropic.Sigma(1, max(walk * np.sqrt(g), 1e-12)) for g in gaps]
        else:
            index = np.zeros(n, dtype=np.int64)
            walks = []
        n_vars = int(index.max()) + 1 if n else 0
        init = np.zeros(n_vars) if initial is None else np.asarray(initial, dtype=float)
        if init.shape != (n_vars,):
            raise ValueError(f"speed scale: initial values must have shape ({n_vars},), got {init.shape}")
        return cls(twists, tau, xi0, dxi, index, gtsam.noiseModel.Isotropic.Sigma(1, float(sigma)),
                   walks, init)

    @property
    def n_variables(self) -> int:
        return int(self.initial.size)

    def factor(self, k: int, noise: gtsam.noiseModel.Base, x_key0: int, x_key1: int,
               bias_key: int | None = None, D: np.ndarray | None = None) -> gtsam.CustomFactor:
        """The motion factor of interval ``k`` (bias-corrected by :attr:`corrections` unless
        the bias is a variable ``bias_key``)."""
        correction = None if (self.corrections is None or bias_key is not None) else self.corrections[k]
        return scaled_motion_factor(x_key0, x_key1, S(int(self.index[k])), self.xi0[k], self.dxi[k],
                                    noise, correction, bias_key, D)

    def add_variables(self, graph: gtsam.NonlinearFactorGraph, values: gtsam.Values) -> None:
        """The scale variables (at :attr:`initial`), the prior on the first and the random walk."""
        for i, s in enumerate(self.initial):
            values.insert(S(i), float(s))
        if self.n_variables:
            graph.add(gtsam.PriorFactorDouble(S(0), 0.0, self.prior))
        for i, noise in enumerate(self.walk):
            graph.add(gtsam.BetweenFactorDouble(S(i), S(i + 1), 0.0, noise))

    def per_interval(self, values: np.ndarray) -> np.ndarray:
        """Variable values (n,) spread to the intervals (T-1,)."""
        return np.asarray(values, dtype=float)[self.index]

    def deltas(self, scale: np.ndarray) -> np.ndarray:
        """The relative motions at the variables' values ``scale`` (n,), corrected by
        :attr:`corrections` (:func:`scaled_deltas`)."""
        return scaled_deltas(self.twists, self.tau, self.per_interval(scale), self.corrections)


def scale_values(values: gtsam.Values, n: int) -> np.ndarray:
    """The scale variables' values (n,) in ``values``."""
    return np.array([values.atDouble(S(i)) for i in range(n)])
