"""How the smoother's marginals scale with the drive's shape: time and peak memory of the
covariance blocks EM and the outputs need (graph/marginals.py) on graphs whose tracks are short
(a chain: a car going forward), come back (a loop: the landmarks of the start seen again at the
end) or are seen throughout (a room: 20 landmarks seen in every frame).

    .venv/bin/python benchmarks/marginals_scaling.py [--frames 500 1000 2000 4541] [--shapes chain loop room]

Prints per shape and length: frames, landmarks, stereo factors, the border's size (long-lived
landmarks kept out of the band), the band (in poses), seconds to linearise and eliminate, to
compute every pose and landmark marginal, and EM's pose-chain blocks (poses, consecutive pairs,
log det), and the process's peak resident memory. Each case runs in its own process, so the
peak is that case's. The graphs are built directly with GTSAM factors (a BetweenFactorPose3
chain, GenericStereoFactor3D observations), linearised at the true values plus noise.
"""

import argparse
import json
import resource
import subprocess
import sys
import time
from dataclasses import dataclass

import gtsam
import numpy as np

from vislam.graph.pose_conversions import L, X

SHAPES = ("chain", "loop", "room")
CALIBRATION = gtsam.Cal3_S2Stereo(500.0, 500.0, 0.0, 320.0, 240.0, 0.5)


@dataclass
class ShapeGraph:
    """A graph on poses ``X(0..T-1)`` and landmarks ``L(j)``, its values and its tracks."""

    graph: gtsam.NonlinearFactorGraph
    values: gtsam.Values
    n_frames: int
    tracks: np.ndarray  # landmark tracks with a variable, sorted
    n_tracks: int
    n_stereo: int


def _look(position: np.ndarray, forward: np.ndarray) -> gtsam.Pose3:
    """A camera pose at ``position`` looking along ``forward`` (z forward, y down)."""
    z = forward / np.linalg.norm(forward)
    x = np.cross(np.array([0.0, 0.0, -1.0]), z)
    x = x / np.linalg.norm(x)
    y = np.cross(z, x)
    return gtsam.Pose3(gtsam.Rot3(np.column_stack([x, y, z])), position)


def trajectory(shape: str, n_frames: int) -> list[gtsam.Pose3]:
    """The true poses: a straight road (chain), a circle driven once (loop), or a platform
    turning slowly in the middle of a room (room), all looking along their direction of
    travel (outward for the room)."""
    k = np.arange(n_frames)
    if shape == "chain":
        return [_look(np.array([1.0 * i, 0.0, 0.0]), np.array([1.0, 0.3, 0.0])) for i in k]
    if shape == "loop":
        a = 2 * np.pi * k / n_frames
        r = n_frames / (2 * np.pi)  # about 1 m a frame
        return [_look(r * np.array([np.cos(t), np.sin(t), 0.0]),
                      np.array([-np.sin(t), np.cos(t), 0.0]) + 0.5 * np.array([np.cos(t), np.sin(t), 0.0]))
                for t in a]
    if shape == "room":  # swings +-0.5 rad about the wall's normal, drifting in a 1 m square
        a = 0.5 * np.sin(2 * np.pi * k / 150.0)
        pos = 0.5 * np.column_stack([np.sin(k / 97.0), np.cos(k / 131.0), 0.1 * np.sin(k / 53.0)])
        return [_look(p, np.array([np.sin(t), np.cos(t), 0.0])) for p, t in zip(pos, a)]
    raise ValueError(f"unknown shape {shape!r}")


def landmarks(shape: str, poses: list[gtsam.Pose3], rng: np.random.Generator) -> np.ndarray:
    """The true landmarks (M, 3): along the road, around the loop, on the room's wall."""
    if shape == "room":  # 20 landmarks on a wall 4 m ahead (y), 4 m wide and 2 m high
        return np.column_stack([rng.uniform(-2, 2, 20), np.full(20, 4.0) + rng.uniform(-0.3, 0.3, 20),
                                rng.uniform(-1, 1, 20)])
    centres = np.array([p.transformFrom(np.array([0.0, 0.0, 8.0])) for p in poses])
    n = 6 * len(poses)  # about 6 new landmarks a frame
    picks = rng.integers(0, len(poses), n)
    return centres[picks] + rng.normal(0.0, 3.0, (n, 3))


def build(shape: str, n_frames: int, seed: int = 0) -> ShapeGraph:
    """:class:`ShapeGraph` of a shape: an odometry chain with a prior on the first pose and a
    stereo observation of every landmark in view (in front, inside the image, at most 25 m
    away); at most 12 observations per landmark on the chain and loop (tracks of a few
    frames), except on the loop, where the landmarks near the start are seen at the end too."""
    rng = np.random.default_rng(seed)
    truth = trajectory(shape, n_frames)
    points = landmarks(shape, truth, rng)
    graph, values = gtsam.NonlinearFactorGraph(), gtsam.Values()
    odo = gtsam.noiseModel.Diagonal.Sigmas(np.r_[np.full(3, 0.005), np.full(3, 0.05)])
    pixel = gtsam.noiseModel.Isotropic.Sigma(3, 1.0)
    graph.add(gtsam.PriorFactorPose3(X(0), truth[0], gtsam.noiseModel.Isotropic.Sigma(6, 1e-3)))
    for k in range(n_frames - 1):
        graph.add(gtsam.BetweenFactorPose3(X(k), X(k + 1), truth[k].between(truth[k + 1]), odo))
    seen = np.zeros(len(points), dtype=int)
    n_stereo = 0
    max_obs = None if shape == "room" else 12
    for k, pose in enumerate(truth):
        cams = gtsam.StereoCamera(pose, CALIBRATION)
        local = (points - pose.translation()) @ pose.rotation().matrix()  # in the camera frame
        near = np.flatnonzero((local[:, 2] > 1.0) & (local[:, 2] < 25.0)
                              & (np.abs(local[:, 0]) < local[:, 2]) & (np.abs(local[:, 1]) < local[:, 2]))
        for j in near:
            if max_obs is not None and seen[j] >= max_obs:
                if not (shape == "loop" and k > n_frames - 30):
                    continue
            z = cams.project(points[j])
            if not (0 <= z.uL() < 640 and 0 <= z.uR() < 640 and 0 <= z.v() < 480):
                continue
            noisy = gtsam.StereoPoint2(z.uL() + rng.normal(), z.uR() + rng.normal(), z.v() + rng.normal())
            graph.add(gtsam.GenericStereoFactor3D(noisy, pixel, X(k), L(int(j)), CALIBRATION))
            seen[j] += 1
            n_stereo += 1
    tracks = np.flatnonzero(seen >= 2)
    for j in np.flatnonzero(seen == 1):  # a single observation: a weak prior determines it
        tracks = np.union1d(tracks, [j])
        graph.add(gtsam.PriorFactorPoint3(L(int(j)), points[j], gtsam.noiseModel.Isotropic.Sigma(3, 10.0)))
    for k, pose in enumerate(truth):
        values.insert(X(k), pose.retract(rng.normal(0.0, 1e-3, 6)))
    for j in tracks:
        values.insert(L(int(j)), points[j] + rng.normal(0.0, 0.05, 3))
    return ShapeGraph(graph, values, n_frames, tracks, len(points), n_stereo)


def measure(shape: str, n_frames: int) -> dict:
    """Build one graph and time its marginals (this process's peak memory included)."""
    from vislam.graph.marginals import linearise, pose_chain_covariances, _schur_marginals

    g = build(shape, n_frames)
    start = time.perf_counter()
    _, reduced = linearise(g.graph, g.values, n_frames, "benchmark")
    t_lin = time.perf_counter() - start
    start = time.perf_counter()
    _schur_marginals(reduced, n_frames, g.n_tracks)
    t_marg = time.perf_counter() - start
    start = time.perf_counter()
    pose_chain_covariances(reduced, n_frames, with_log_det=True)
    t_em = time.perf_counter() - start
    peak = resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024.0
    border = 0 if reduced.border is None else len(reduced.border.tracks)
    return {"shape": shape, "frames": n_frames, "landmarks": len(g.tracks), "stereo": g.n_stereo,
            "border": border, "band": (reduced.w + 1) // 6, "linearise_s": t_lin,
            "marginals_s": t_marg, "em_blocks_s": t_em, "peak_mib": peak}


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--frames", type=int, nargs="+", default=[500, 1000, 2000, 4541])
    ap.add_argument("--shapes", nargs="+", default=list(SHAPES), choices=SHAPES)
    ap.add_argument("--case", nargs=2, metavar=("SHAPE", "FRAMES"), help=argparse.SUPPRESS)
    args = ap.parse_args()
    if args.case:  # one case, in this process: a JSON line back to the parent
        print(json.dumps(measure(args.case[0], int(args.case[1]))))
        return
    print(f"{'shape':6} {'frames':>6} {'landmarks':>9} {'stereo':>7} {'border':>6} {'band':>5} "
          f"{'linearise':>9} {'marginals':>9} {'EM blocks':>9} {'peak MiB':>8}")
    for shape in args.shapes:
        for n in args.frames:
            out = subprocess.run([sys.executable, __file__, "--case", shape, str(n)],
                                 capture_output=True, text=True)
            if out.returncode:
                print(f"{shape:6} {n:6d} failed: {out.stderr.strip().splitlines()[-1:]}")
                continue
            r = json.loads(out.stdout.strip().splitlines()[-1])
            print(f"{r['shape']:6} {r['frames']:6d} {r['landmarks']:9d} {r['stereo']:7d} "
                  f"{r['border']:6d} {r['band']:5d} {r['linearise_s']:8.2f}s {r['marginals_s']:8.2f}s "
                  f"{r['em_blocks_s']:8.2f}s {r['peak_mib']:8.0f}", flush=True)


if __name__ == "__main__":
    main()
