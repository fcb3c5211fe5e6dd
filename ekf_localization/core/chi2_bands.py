"""χ² bounds for consistency tests, shared by the node's diagnostics, the guard and the tools. No ROS.

The NIS νᵀS⁻¹ν of a consistent filter's update is χ²(m); the mean of K independent ones lies
in [χ²_a(Km)/K, χ²_{1-a}(Km)/K] with probability 1 - 2a (Bar-Shalom, Li, Kirubarajan,
*Estimation with Applications to Tracking and Navigation*, sec. 5.4).
"""

from __future__ import annotations

from functools import lru_cache

from scipy.special import chdtri

BAND_MASS = 0.95


@lru_cache(maxsize=1024)
def chi2_quantile(mass: float, dof: float) -> float:
    """The ``mass`` quantile of χ²(dof): scipy.stats.chi2.ppf(mass, dof) through scipy.special
    (scipy.stats costs 0.7 s of start-up), cached for the few (mass, dof) a filter asks for."""
    return float(chdtri(dof, 1.0 - mass))


def mean_chi2_band(dof: int, samples: float, mass: float = BAND_MASS) -> tuple[float, float]:
    """The ``mass`` band of the mean of ``samples`` independent χ²(dof) values (``samples`` may be
    an effective, non-integer count)."""
    if samples < 1:
        return float("nan"), float("nan")
    a = (1.0 - mass) / 2.0
    k = dof * samples
    return chi2_quantile(a, k) / samples, chi2_quantile(1.0 - a, k) / samples
