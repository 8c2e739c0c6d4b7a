"""ekf-joint under three readings of the "mean" pairing's interval noise, on default simulated
drives under their true model (docs/findings.md, "The mean pairing's intervals are not
independent").

    .venv/bin/python benchmarks/mean_pairing.py --seeds 8 --frames 600

- ``white intervals``: each interval independent with the interval's white sigma (sigma / sqrt(2)),
  what an identified model gave before 2026-12-04: over a stretch, half the variance;
- ``long-run``: each interval independent with the long-run sigma (the sample's), what
  ``ekf.model.model_config`` gives now;
- ``MA(1) exact``: the shared sample's twist noise carried as 6 more core rows (interval k's
  error ``tau (n_k + n_(k+1)) / 2``, ``n_(k+1)`` held for interval k + 1): right on every horizon.
  A subclass here, not a product path.

Prints each drive's aligned ATE (m) and mean pose NEES, and their means.
"""

from __future__ import annotations

import argparse

import numpy as np

from vislam.ekf import joint as J


class MAState(J.JointState):
    """JointState with the shared sample's noise as core rows after the bias and scale."""

    def __init__(self, config, n_tracks, textbook=False):
        super().__init__(config, n_tracks, textbook)
        c = self.core
        P = np.zeros((c + 6, c + 6))
        P[:c, :c] = self.P
        P[c:, c:] = config.velocity_cov  # n_0
        self.P, self.core = P, c + 6

    def predict(self, tau, u, config):
        """Interval k's error ``tau (n_k + n_(k+1)) / 2`` with ``n_k`` these rows, then
        ``n_(k+1)`` in them: ``Phi = [[Phi_b, E], [0, 0]]``, noise ``[E; I] W [E; I]^T``."""
        u_c, Phi_b, Q_b = self.transition(tau, u, config)
        Q_b[:6, :6] = 0.0  # the twist noise enters through the sample rows instead
        b, c = self.base, self.core
        E = np.zeros((b, 6))
        E[:6] = 0.5 * tau * np.eye(6)
        Phi = np.zeros((c, c))
        Phi[:b, :b] = Phi_b
        Phi[:b, b:] = E
        G = np.vstack([E, np.eye(6)])
        Q = np.zeros((c, c))
        Q[:b, :b] = Q_b
        Q += G @ self.W @ G.T
        self.propagate(tau, u_c, Phi, Q)


class MAEKF(J.JointEKF):
    def initialise(self, seq, config, guard):
        super().initialise(seq, config, guard)
        self.state = MAState(config, seq.n_tracks, self.textbook)
        self.max_dim = self.state.state_dim


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--seeds", type=int, default=8, help="default drives (seeds 0..N-1)")
    parser.add_argument("--frames", type=int, default=600, help="frames per drive")
    args = parser.parse_args(argv)

    import vislam.ekf.model as M
    from vislam.ekf.config import FilterConfig
    from vislam.ekf.driver import run_filter
    from vislam.eval.consistency import pose_nees
    from vislam.eval.metrics import ate_rmse
    from vislam.eval.sim_config import SimConfig
    from vislam.eval.simulate import DEFAULT_SIM, simulate, true_model

    ratio = M.white_sample_ratio
    res: dict[str, list] = {}
    try:
        for seed in range(args.seeds):
            sim = simulate(SimConfig(**{**DEFAULT_SIM.__dict__, "seed": seed, "n_frames": args.frames}))
            frames = np.arange(len(sim.poses))
            for tag in ("white intervals", "long-run", "MA(1) exact"):
                M.white_sample_ratio = (lambda p: 1.0) if tag == "white intervals" else ratio
                seq, cfg = M.apply_model(sim.sequence, FilterConfig(), true_model(sim))
                est = run_filter(MAEKF(), seq, cfg) if tag.startswith("MA") else J.run_joint(seq, cfg)
                res.setdefault(tag, []).append((ate_rmse(est.poses, sim.poses, align="se3"),
                                                np.nanmean(pose_nees(est, frames, sim.poses))))
    finally:
        M.white_sample_ratio = ratio
    for tag, v in res.items():
        v = np.array(v)
        print(f"{tag:16s} ATE " + " ".join(f"{x:.3f}" for x in v[:, 0]) + f"  mean {v[:, 0].mean():.4f}"
              + "  NEES " + " ".join(f"{x:.2f}" for x in v[:, 1]) + f"  mean {v[:, 1].mean():.2f}")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
