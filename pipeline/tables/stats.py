"""Paired comparisons of runs: the mean of paired differences (same seed, or same seed and scene for means
over scenes) with its two-sided 95% Student-t interval. With the three seeds a table usually has, the t
interval is wide (t = 4.30 at 2 degrees of freedom); a percentile bootstrap over three seeds has only ten
distinct resamples and would be narrower than the data justify."""

import math
from dataclasses import dataclass

import numpy as np
import pandas as pd
from jaxtyping import Float
from scipy import stats

LEVEL = 0.95


@dataclass(frozen=True)
class Interval:
    """Mean of paired differences with its two-sided 95% Student-t interval over ``n`` pairs (NaN bounds
    below two pairs: no spread to estimate)."""

    mean: float
    low: float
    high: float
    n: int

    @staticmethod
    def of(diffs: Float[np.ndarray, " n"]) -> "Interval":
        diffs = diffs[np.isfinite(diffs)]
        n = len(diffs)
        if n == 0:
            return Interval(math.nan, math.nan, math.nan, 0)
        mean = float(diffs.mean())
        if n < 2:
            return Interval(mean, math.nan, math.nan, n)
        half = float(stats.t.ppf(0.5 + LEVEL / 2, n - 1) * diffs.std(ddof=1) / math.sqrt(n))
        return Interval(mean, mean - half, mean + half, n)

    @property
    def above_zero(self) -> bool:
        """The interval lies above zero (False when it is undefined)."""
        return bool(self.low > 0.0)

    @property
    def excludes_zero(self) -> bool:
        """The interval lies above or below zero (False when it is undefined)."""
        return bool(self.low > 0.0 or self.high < 0.0)

    def text(self) -> str:
        """'+0.21 [+0.01, +0.42]' in the unit of the differences; the mean alone without bounds, '-' without a
        mean."""
        if not math.isfinite(self.mean):
            return "-"
        if not (math.isfinite(self.low) and math.isfinite(self.high)):
            return f"{self.mean:+.2f}"
        return f"{self.mean:+.2f} [{self.low:+.2f}, {self.high:+.2f}]"


def paired(a: pd.Series, b: pd.Series) -> Interval:
    """``Interval.of(a - b)`` over the keys (seeds, or (seed, scene) pairs) where both have a finite value."""
    both = pd.concat([a.rename("a"), b.rename("b")], axis=1, join="inner").dropna()
    return Interval.of((both["a"] - both["b"]).to_numpy(float))
