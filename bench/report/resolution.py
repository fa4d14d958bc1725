"""Resolution of a paired design: what the Wilcoxon signed-rank test with Holm can and cannot see.

A comparison of two optimisers over ``n`` shared instances is a two-sided Wilcoxon signed-rank
test on the ``n`` paired differences, one test of a family of ``m`` (``family_size``) corrected
by Holm's step-down method. Three numbers state what such a comparison could have found:

- **Floor.** The smallest two-sided p the exact signed-rank test reaches with ``n`` non-zero
  differences is 2 / 2^n (all differences of one sign); Holm's first step multiplies the
  smallest p by ``m``, so no comparison of the family can get below ``m * 2 / 2^n``. When that
  floor is at or above alpha the design cannot reach a verdict, whatever the data
  (``design_floor``).
- **Minimum detectable difference** (``min_detectable_difference``), at power 0.8 and level
  alpha / m (Holm's first, strictest threshold). Normal approximation: the paired t-test's
  detectable shift (z_{1-alpha/(2m)} + z_{power}) * s_d / sqrt(n), from the standard deviation
  s_d of the observed differences, inflated by sqrt(pi / 3), the inverse square root of the
  signed-rank test's asymptotic relative efficiency to the t-test under normal differences
  (3 / pi). Infinite when the floor is not below alpha: the exact test cannot reject.
- **Instances needed** (``instances_needed``): bootstrap the observed differences (the effect
  as seen, spread included) to ``n`` pairs, ``n_boot`` times, and count the fraction whose
  signed-rank p (exact null up to 50 pairs, normal beyond) is below alpha / m; the smallest n
  whose fraction reaches the power, by bisection between the floor's minimum and ``cap``
  (the fraction is taken as increasing in n). The same seeded generator is reused at every n,
  so the answer is reproducible; inf when even ``cap`` instances fall short.

Hand-written: no library states the exact signed-rank floor or plans the sample size of a
signed-rank test (statsmodels' power classes cover t-, z- and F-tests only).
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
from scipy import stats as sps

from bench.report.stats import StatsError

FAMILIES = ("leader", "all")
N_CAP = 200
N_BOOT = 400


def family_size(n_optimizers: int, family: str = "leader") -> int:
    """Tests in the post-hoc family: k - 1 against the leader, k (k - 1) / 2 for all pairs."""
    if family not in FAMILIES:
        raise StatsError(f"family must be one of {FAMILIES}, got {family!r}")
    k = int(n_optimizers)
    return k - 1 if family == "leader" else k * (k - 1) // 2


def wilcoxon_floor(n_pairs: int, m: int = 1) -> float:
    """Smallest Holm-adjusted two-sided p of an exact signed-rank test on n non-zero pairs."""
    if n_pairs < 1:
        return 1.0
    return min(1.0, m * 2.0 ** (1 - n_pairs))


@dataclass(frozen=True)
class DesignFloor:
    """What a complete block design can reach: see ``design_floor``."""

    n_instances: int
    n_optimizers: int
    family: str
    family_size: int
    p_floor: float       # the smallest p any comparison of the family can reach after Holm
    alpha: float
    reachable: bool      # p_floor < alpha: a difference can be declared at all
    min_instances: int   # the fewest instances for which p_floor < alpha


def design_floor(n_instances: int, n_optimizers: int, family: str = "leader",
                 alpha: float = 0.05) -> DesignFloor:
    """Whether ``n_instances`` shared instances of ``n_optimizers`` can reach ``alpha`` at all."""
    if not 0 < alpha < 1:
        raise StatsError(f"alpha must be in (0, 1), got {alpha!r}")
    if n_optimizers < 2:
        raise StatsError(f"n_optimizers must be at least 2, got {n_optimizers!r}")
    m = family_size(n_optimizers, family)
    floor = wilcoxon_floor(n_instances, m)
    # m * 2^(1-n) < alpha  <=>  n > 1 + log2(m / alpha)
    min_n = math.floor(1 + math.log2(m / alpha)) + 1
    return DesignFloor(int(n_instances), int(n_optimizers), family, m, floor, alpha,
                       floor < alpha, min_n)


def min_detectable_difference(d: np.ndarray, m: int = 1, alpha: float = 0.05,
                              power: float = 0.8) -> float:
    """Shift of the paired differences d (n,) detectable with ``power`` at alpha / m (see the
    module doc); inf when the exact floor cannot go below alpha / m, NaN with fewer than 2."""
    d = np.asarray(d, float).ravel()
    if d.size < 2:
        return np.nan
    if wilcoxon_floor(d.size, m) >= alpha:
        return np.inf
    z = sps.norm.ppf(1 - alpha / (2 * m)) + sps.norm.ppf(power)
    return float(z * np.std(d, ddof=1) * math.sqrt(math.pi / 3) / math.sqrt(d.size))


def bootstrap_power(d: np.ndarray, n: int, level: float, rng_seed: int = 0,
                    n_boot: int = N_BOOT) -> float:
    """Fraction of ``n_boot`` resamples of d at size n whose signed-rank p is below ``level``."""
    d = np.asarray(d, float).ravel()
    rng = np.random.default_rng(rng_seed)
    sample = d[rng.integers(0, d.size, size=(n_boot, n))]
    # Resamples always hold ties, on which scipy's "auto" runs a permutation test per row (slow);
    # the exact null with scipy's conservative rounding up to 50 pairs, the normal one beyond.
    method = "exact" if n <= 50 else "asymptotic"
    with np.errstate(invalid="ignore", divide="ignore"):
        p = sps.wilcoxon(sample, axis=1, method=method).pvalue  # all-zero rows: NaN, nothing to detect
    return float(np.mean(np.nan_to_num(p, nan=1.0) < level))


def instances_needed(d: np.ndarray, m: int = 1, alpha: float = 0.05, power: float = 0.8,
                     cap: int = N_CAP, seed: int = 0, n_boot: int = N_BOOT) -> float:
    """Instances at which the comparison whose paired differences are d (n,) would be declared
    with probability ``power`` at Holm's first-step level alpha / m (see the module doc); inf
    beyond ``cap``, NaN with fewer than 2 differences."""
    d = np.asarray(d, float).ravel()
    if d.size < 2:
        return np.nan
    if not np.any(d):
        return np.inf
    level = alpha / m
    lo = max(2, math.floor(1 + math.log2(m / alpha)) + 1)  # below lo the exact floor forbids it
    if lo > cap or bootstrap_power(d, cap, level, seed, n_boot) < power:
        return np.inf
    hi = cap
    if bootstrap_power(d, lo, level, seed, n_boot) >= power:
        return float(lo)
    while hi - lo > 1:  # invariant: power(lo) < target <= power(hi)
        mid = (lo + hi) // 2
        if bootstrap_power(d, mid, level, seed, n_boot) >= power:
            hi = mid
        else:
            lo = mid
    return float(hi)
