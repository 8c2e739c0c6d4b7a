"""A fingerprint of a set of arrays that is the same on every machine: "unchanged" to 1e-12 of
each array's size, not to the byte.

A sha256 of the arrays' bytes pinned the simulators' drives on the machine it was computed on,
and on no other: the simulators multiply matrices through numpy's BLAS, whose kernel is chosen
by the processor, and another kernel rounds the last bit differently (measured: the same drive
under ``OPENBLAS_CORETYPE=Prescott`` has another sha256 on the same machine). So each array is
summed instead: integer arrays exactly, float arrays to 1e-12 of their size. Each array gives its
dtype, shape and two sums, plain and weighted (weights that tell one element from another, made
by IEEE-exact operations, so that they are the same everywhere), which a change of draws, of
their order or of any value by more than rounding moves.
"""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np

#: The simulators' drives pinned by the tests, by name (tests/test_sim_scenarios.py,
#: tests/test_sim_faults.py).
SIM_FINGERPRINTS = Path(__file__).with_name("sim_fingerprints.json")

#: Float sums agree to this fraction of the array's sum of absolute values (measured between two
#: BLAS kernels on the pinned drives: at most 2.5e-15).
RTOL = 1e-12


def _weights(n: int) -> np.ndarray:
    return 1.0 + np.fmod(np.arange(n, dtype=np.float64) * 0.6180339887498949, 1.0)


def fingerprint(arrays) -> list[tuple]:
    """Per array: (dtype, shape, size sum, weighted sum); for floats the size sum is the sum of
    absolute values, for integers and booleans the plain sum (both exact for integers)."""
    out = []
    for a in arrays:
        a = np.asarray(a)
        flat = a.ravel()
        if np.issubdtype(a.dtype, np.floating):
            flat = flat.astype(np.float64)
            sums = (float(np.sum(np.abs(flat))), float(_weights(flat.size) @ flat))
        else:
            flat = flat.astype(np.int64)
            w = np.arange(flat.size, dtype=np.int64) % 1009 + 1
            sums = (int(flat.sum()), int((w * flat).sum()))
        out.append((str(a.dtype), tuple(a.shape)) + sums)
    return out


def pinned(name: str) -> list[tuple]:
    """The fingerprint pinned for ``name`` in SIM_FINGERPRINTS."""
    return [(e[0], tuple(e[1]), *e[2:]) for e in json.loads(SIM_FINGERPRINTS.read_text())[name]]


def assert_same_fingerprint(got: list[tuple], expected: list[tuple]) -> None:
    """Each array's dtype, shape and integer sums equal; its float sums within RTOL."""
    __tracebackhide__ = True
    assert len(got) == len(expected), f"{len(got)} arrays, expected {len(expected)}"
    for i, (g, e) in enumerate(zip(got, expected)):
        assert g[:2] == tuple(e[:2]), f"array {i}: dtype/shape {g[:2]}, expected {tuple(e[:2])}"
        if g[0].startswith("float"):
            scale = max(abs(e[2]), 1e-300)
            for name, x, y in (("sum |a|", g[2], e[2]), ("weighted sum", g[3], e[3])):
                assert abs(x - y) <= RTOL * scale, (
                    f"array {i} ({g[0]} {g[1]}): {name} {x!r}, expected {y!r}")
        else:
            assert g[2:] == tuple(e[2:]), f"array {i} ({g[0]} {g[1]}): sums {g[2:]}, expected {tuple(e[2:])}"
