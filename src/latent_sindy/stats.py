"""Intervals of success rates: the 95 % Wilson score interval every table and report uses.

    >>> [round(end, 3) for end in wilson_interval(45, 50)]   # 45 of 50 episodes succeeded
    [0.786, 0.957]
    >>> wilson_interval(0, 0)                                 # no episodes: no interval
    (nan, nan)
"""

from __future__ import annotations

import math

from latent_sindy.errors import UserError

__all__ = ["Z95", "wilson_interval"]

Z95 = 1.959964
"""The standard normal quantile of 0.975 (a two-sided 95 % interval)."""


def wilson_interval(successes: int, n: int, z: float = Z95) -> tuple[float, float]:
    """The Wilson score interval (95 % by default) of ``successes`` in ``n`` trials.

    Well behaved at 0 and ``n`` successes (the interval then ends at the rate itself). With
    ``n = 0`` there is no rate to bound, so both ends are NaN, as the rate 0/0 is; tables
    write no interval there. UserError unless 0 <= successes <= n.
    """
    if n < 0 or not 0 <= successes <= n:
        raise UserError(f"wilson_interval: {successes} successes in {n} trials; give "
                        "0 <= successes <= trials")
    if n == 0:
        return (math.nan, math.nan)
    p = successes / n
    centre = (p + z * z / (2 * n)) / (1 + z * z / n)
    half = z * math.sqrt(p * (1 - p) / n + z * z / (4 * n * n)) / (1 + z * z / n)
    return (max(0.0, centre - half), min(1.0, centre + half))
