"""The numbers and readings of ``vislam compare`` (:mod:`eval.compare`): figures at four
significant digits, the change ``B − A`` absolute and relative, the reading of a change
(better / worse / same, closer to the chi-square band), and Welch's t-test of the run-to-run
spread of Monte Carlo folders."""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

#: Significance level of the run-to-run spread test.
SPREAD_ALPHA = 0.05
#: Relative change under which a figure reads "same" (neither better nor worse).
SAME_RTOL = 1e-3
#: A cell where the folder holds the estimator but has no value.
NO_VALUE = "n/a"
#: A cell where the folder does not hold the estimator (or the setting).
ABSENT = "–"


def num(x: float | None) -> str:
    """A figure at 4 significant digits (powers of ten as 6.18e-5); None as n/a."""
    if x is None:
        return NO_VALUE
    if x == 0:
        return "0"
    a = abs(x)
    if a >= 1e5 or a < 1e-3:
        mantissa, exponent = f"{x:.3e}".split("e")
        return f"{mantissa}e{int(exponent)}"
    decimals = max(0, 3 - math.floor(math.log10(a)))
    text = f"{x:.{decimals}f}"
    return "0" if float(text) == 0 else text


def signed(x: float) -> str:
    text = num(x)
    return text if text.startswith("-") or text == "0" else "+" + text


def relative(delta: float, base: float | None) -> str | None:
    if base is None or base == 0:
        return None
    r = 100.0 * delta / abs(base)
    if r == 0:
        return "0 %"
    if abs(r) < 10:
        return f"{r:+.2f} %"
    return f"{r:+.1f} %" if abs(r) < 1000 else f"{r:+.0f} %"


def band_distance(x: float, band: tuple[float, float]) -> float:
    """How far ``x`` lies outside ``band`` on a log scale (0 inside)."""
    lo, hi = band
    if x <= 0:
        return math.inf
    if x > hi:
        return math.log(x / hi)
    if x < lo:
        return math.log(lo / x)
    return 0.0


def same(a: float, b: float) -> bool:
    """Equal within :data:`SAME_RTOL` of the larger magnitude."""
    return abs(b - a) <= SAME_RTOL * max(abs(a), abs(b))


def reading(sense: str, a: float, b: float, band_a=None, band_b=None) -> str:
    """The word for ``b`` against the baseline ``a``."""
    if sense == "lower":
        if same(a, b):
            return "same"
        return "better" if b < a else "worse"
    if sense == "band" and band_a is not None and band_b is not None:
        da, db = band_distance(a, band_a), band_distance(b, band_b)
        if da == 0 and db == 0:
            return "same" if same(a, b) else "both inside the band"
        if same(a, b) and same(band_a[0], band_b[0]) and same(band_a[1], band_b[1]):
            return "same"
        if db < da:
            return "better (closer to the band)" if db else "better (inside the band)"
        if db > da:
            return "worse (further from the band)" if da else "worse (outside the band)"
        return "same"
    return "same" if same(a, b) else ""


@dataclass
class Change:
    """``B − A`` for one figure: absolute, relative (text) and the reading."""

    delta: float
    rel: str | None
    verdict: str
    p_value: float | None = None
    beyond: bool | None = None

    def text(self) -> str:
        return signed(self.delta) + (f" ({self.rel})" if self.rel else "")


def change(sense: str, a: float | None, b: float | None, band_a=None, band_b=None) -> Change | None:
    if a is None or b is None:
        return None
    d = b - a
    return Change(d, relative(d, a), reading(sense, a, b, band_a, band_b))


def spread_test(a: list[float], b: list[float], alpha: float = SPREAD_ALPHA):
    """Welch's t-test on two sets of per-run means: (p value, beyond the spread), or
    (None, None) with fewer than two values on a side."""
    from scipy import stats

    x = np.asarray([v for v in a if v is not None], dtype=float)
    y = np.asarray([v for v in b if v is not None], dtype=float)
    if x.size < 2 or y.size < 2:
        return None, None
    if np.var(x) == 0 and np.var(y) == 0:  # no spread: any difference is beyond it
        same = float(np.mean(x)) == float(np.mean(y))
        return (1.0, False) if same else (0.0, True)
    p = float(stats.ttest_ind(x, y, equal_var=False).pvalue)
    return p, bool(p < alpha)


def run_summary(values: list[float | None]) -> str:
    """'mean, median (min, max)' of the per-run values that have one."""
    v = np.asarray([x for x in values if x is not None], dtype=float)
    if v.size == 0:
        return NO_VALUE
    return (f"{num(float(v.mean()))}, {num(float(np.median(v)))} "
            f"({num(float(v.min()))}, {num(float(v.max()))})")


def clip(text: str, n: int = 60) -> str:
    """``text`` on one line, at most ``n`` characters."""
    text = " ".join(str(text).split())
    return text if len(text) <= n else text[: n - 3] + "..."

