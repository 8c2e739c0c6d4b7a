"""The fingerprint that pins the simulators' drives (tests/fingerprint.py) tells a changed drive
from the same drive rounded differently."""

import numpy as np
import pytest

from tests.fingerprint import assert_same_fingerprint, fingerprint


@pytest.fixture
def arrays():
    rng = np.random.default_rng(0)
    return [rng.normal(size=(500, 4)) * 300.0, rng.integers(0, 900, 2000), np.eye(4)]


def test_last_bit_rounding_passes(arrays):
    rounded = [a * (1 + 4e-16) if a.dtype.kind == "f" else a for a in arrays]
    assert any(not np.array_equal(a, b) for a, b in zip(arrays, rounded))
    assert_same_fingerprint(fingerprint(rounded), fingerprint(arrays))


@pytest.mark.parametrize("change", ["one value", "two swapped", "one integer", "shape", "dtype"])
def test_a_changed_array_fails(arrays, change):
    moved = [a.copy() for a in arrays]
    if change == "one value":
        moved[0][123, 2] += 1e-4
    elif change == "two swapped":
        moved[0][[3, 4]] = moved[0][[4, 3]]
    elif change == "one integer":
        moved[1][7] += 1
    elif change == "shape":
        moved[2] = moved[2].reshape(2, 8)
    else:
        moved[2] = moved[2].astype(np.float32)
    with pytest.raises(AssertionError):
        assert_same_fingerprint(fingerprint(moved), fingerprint(arrays))
