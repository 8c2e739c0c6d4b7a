"""Memory of a drive grows with its observations, not with tracks x frames (issue 36, item 1).

Simulates drives of several lengths (`vislam simulate`, the sparse track format), and prints
per drive: frames, tracks, observations, the file's size, and the peak resident memory of
loading it alone and of `vislam run -e ekf-invariant` on it. Each is measured in a fresh
process as its own high-water mark (``VmHWM`` of /proc/self/status: not ``ru_maxrss``, which a
child inherits from its parent). With ``--dense-up-to N`` the drives of at most N frames are
also written in the dense layout (``features`` (4, M, T), in a child process) and measured the
same way, for comparison. Linux only (/proc).

    python benchmarks/drive_memory.py [--frames 600 1200 2400 4800] [--dense-up-to 1200]

Measured 2026-11-27 on the project's two-core machine shared with other jobs (load average
about 15, so the seconds are slow and noisy; the memory figures are not), seed 0, python with
vislam.eval.loader imported alone 30 MiB:

    layout frames  tracks observations  file MB  load MiB  run MiB
    sparse    600    5630        45943      1.5        36      119
     dense    600    5630        45943      1.8       149      222
    sparse   1200   10916        90291      2.9        41      126
     dense   1200   10916        90291      3.9       493      565
    sparse   2400   21375       177738      5.7        52      143
    sparse   4800   43522       359625     11.5        73      169

Before the sparse layout, `vislam simulate --frames 4800` was refused (its dense array: 6.2
GiB) and `vislam run` held 1.9 GB at 2,400 frames.
"""

from __future__ import annotations

import argparse
import subprocess
import sys
import tempfile
import time
from pathlib import Path

#: Runs ``load FILE`` (load_sequence alone), ``import`` (nothing but the import) or
#: ``cli ARGS...`` (a vislam command in this process), then prints its peak resident KiB.
RUNNER = """
import sys
from vislam.eval.loader import load_sequence
if sys.argv[1] == "load":
    load_sequence(sys.argv[2])
elif sys.argv[1] == "cli":
    from vislam.eval.cli import main
    rc = main(sys.argv[2:])
    if rc:
        raise SystemExit(rc)
with open("/proc/self/status") as f:
    print(next(line.split()[1] for line in f if line.startswith("VmHWM:")))
"""

#: Writes the drive of argv[1] in the dense layout to argv[2] (builds the (4, M, T) array).
DENSE = """
import sys
from vislam.eval.loader import load_sequence, write_npz
seq = load_sequence(sys.argv[1])
cal = seq.calibration
write_npz(sys.argv[2], time_stamps=seq.timestamps, features=seq.obs.to_dense(seq.n_tracks),
          linear_velocity=seq.linear_velocity.T, angular_velocity=seq.angular_velocity.T,
          K=cal.K, b=cal.baseline, cam_T_imu=cal.cam_T_imu)
"""


def peak_rss(*args: str) -> tuple[float, float]:
    """Peak resident memory (MiB) and wall time (s) of ``RUNNER args`` in a fresh process."""
    start = time.perf_counter()
    done = subprocess.run([sys.executable, "-c", RUNNER, *args], capture_output=True, text=True)
    wall = time.perf_counter() - start
    if done.returncode != 0:
        raise SystemExit(f"{' '.join(args)} failed ({done.returncode}): {done.stderr.strip()}")
    return int(done.stdout.split()[-1]) / 1024.0, wall


def vislam(*args: str) -> list[str]:
    return [sys.executable, "-m", "vislam.eval.cli", *args]


def measure(path: Path, work: Path, layout: str, frames: int) -> dict:
    from vislam.eval.loader import read_calibration
    from vislam.eval.safe_reading import read_npz

    n = read_npz(path, ("n_tracks", "obs_frame"))
    _, T = read_calibration(path)
    load_mib, load_s = peak_rss("load", str(path))
    run_mib, run_s = peak_rss("cli", "run", str(path), "-e", "ekf-invariant", "-q",
                              "--no-plots", "--out", str(work / f"run-{layout}-{frames}"))
    return {"layout": layout, "frames": T, "size_mb": path.stat().st_size / 1e6,
            "load_mib": load_mib, "load_s": load_s, "run_mib": run_mib, "run_s": run_s,
            "tracks": int(n["n_tracks"]) if "n_tracks" in n else None,
            "observations": int(n["obs_frame"].size) if "obs_frame" in n else None}


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--frames", type=int, nargs="+", default=[600, 1200, 2400, 4800])
    ap.add_argument("--dense-up-to", type=int, default=1200, metavar="N",
                    help="also measure the dense layout for drives of at most N frames "
                         "(0: never; the dense array of 2,400 frames takes 1.6 GiB)")
    ap.add_argument("--seed", type=int, default=0)
    args = ap.parse_args()
    base_mib, _ = peak_rss("import")
    print(f"python + vislam.eval.loader imported: {base_mib:.0f} MiB peak resident")
    print(f"{'layout':>6} {'frames':>6} {'tracks':>7} {'observations':>12} {'file MB':>8} "
          f"{'load MiB':>9} {'load s':>7} {'run MiB':>8} {'run s':>6}")
    with tempfile.TemporaryDirectory(prefix="vislam-drive-memory-") as tmp:
        work = Path(tmp)
        for frames in args.frames:
            name = f"sim-{frames}"
            subprocess.run(vislam("simulate", "--out", str(work), "--force", "--seed",
                                  str(args.seed), "--frames", str(frames), "--name", name),
                           check=True, stdout=subprocess.DEVNULL)
            sparse = work / f"{name}.npz"
            rows = [measure(sparse, work, "sparse", frames)]
            if frames <= args.dense_up_to:
                dense = work / f"{name}-dense.npz"
                subprocess.run([sys.executable, "-c", DENSE, str(sparse), str(dense)],
                               check=True)
                (work / "groundtruth" / f"{dense.stem}.txt").write_bytes(
                    (work / "groundtruth" / f"{name}.txt").read_bytes())
                row = measure(dense, work, "dense", frames)
                row.update(tracks=rows[0]["tracks"], observations=rows[0]["observations"])
                rows.append(row)
            for r in rows:
                print(f"{r['layout']:>6} {r['frames']:>6} {r['tracks']:>7} "
                      f"{r['observations']:>12} {r['size_mb']:>8.1f} {r['load_mib']:>9.0f} "
                      f"{r['load_s']:>7.1f} {r['run_mib']:>8.0f} {r['run_s']:>6.1f}", flush=True)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
