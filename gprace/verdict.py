"""Verdicts from enough data: the one rule of every claims table (head-to-head, its study, the time trial).

A claim of the paper is a difference (exploration - baseline) with a claimed sign. It ``holds``
where the 95 % interval of the difference lies on the claimed side in every seed, ``fails`` where
it lies on the other side in every seed, ``seeds disagree`` where seeds show both, ``not
resolved`` otherwise, and ``too few samples for a verdict`` below :data:`MIN_SAMPLES` samples
(tracks of the head-to-head, trials of the time trial), whatever the interval says.

Why a minimum: the intervals are bootstrap intervals over the samples, and with a handful of
samples the bootstrap has almost nothing to resample (2 tracks give 3 distinct resample means, so
two tracks that agree in sign give an interval that excludes 0 and a "holds"). The minimum is the
smallest ``n`` at which any test that assumes nothing about the distribution could reject "no
difference" at the 5 % level at all: the two-sided sign test with all ``n`` samples on one side
has ``p = 2 * 0.5**n``, below 0.05 from ``n = 6`` on (``n = 5``: 0.0625). Below it no data could
support a verdict, so none is given.
"""

from __future__ import annotations

from collections.abc import Sequence

import numpy as np

LEVEL = 0.95
TOO_FEW = "too few samples for a verdict"


def min_samples(level: float = LEVEL) -> int:
    """Smallest ``n`` with ``2 * 0.5**n < 1 - level`` (see the module docstring): 6 at 95 %."""
    n = 1
    while 2.0 * 0.5**n >= 1.0 - level:
        n += 1
    return n


MIN_SAMPLES = min_samples()


def verdict(intervals: Sequence[Sequence[float | None]], claimed: int = -1, n: int | None = None) -> str:
    """The verdict from each seed's interval ``(lo, hi)`` of the difference, the claimed sign (-1:
    exploration lowers the figure) and the samples behind the intervals (``n``, the fewest over
    seeds; None: unknown, judged on the intervals alone)."""
    if n is not None and n < MIN_SAMPLES:
        return TOO_FEW
    side = []
    for lo, hi in intervals:
        if lo is None or hi is None:
            side.append(0)
        elif claimed * hi > 0 and claimed * lo > 0:
            side.append(1)  # the whole interval on the claimed side
        elif claimed * hi < 0 and claimed * lo < 0:
            side.append(-1)
        else:
            side.append(0)
    if side and all(s == 1 for s in side):
        return "holds"
    if side and all(s == -1 for s in side):
        return "fails"
    if 1 in side and -1 in side:
        return "seeds disagree"
    return "not resolved"


def mean_interval(values: Sequence[float], B: int = 2000, seed: int = 0, level: float = LEVEL) -> list[float | None]:
    """Percentile bootstrap interval of the mean of the finite ``values`` (``[None, None]`` without any)."""
    v = np.asarray([x for x in values if x is not None and np.isfinite(x)], float)
    if not len(v):
        return [None, None]
    W = np.random.default_rng(seed).multinomial(len(v), np.full(len(v), 1.0 / len(v)), size=B)
    means = W @ v / len(v)
    a = 100 * (1 - level) / 2
    return [float(np.percentile(means, a)), float(np.percentile(means, 100 - a))]
