"""The tail of a residual's magnitude: exceedance clusters, a generalized Pareto fit, rates and levels.

A false alarm of the collision detector (12) is one *excursion* of |r_j| above zeta_j: the detector latches
(or the reaction starts) at the first tick over, so the ticks that follow in the same excursion are not
new alarms. The rate of false alarms at a level z is therefore the rate of *clusters* of exceedances
(runs declustering, Coles 2001, Sec. 5.3.2: exceedances closer than ``gap`` seconds form one cluster).

Peaks over threshold (Coles 2001, Sec. 4.3; Davison & Smith 1990): above a high level u the cluster maxima
of a stationary process exceed u at a rate lambda_u [1/h] (counted in the log) and their excesses follow a
generalized Pareto distribution (GPD) with scale sigma and shape xi, so for z >= u

    rate(z) = lambda_u * (1 + xi (z - u) / sigma) ** (-1 / xi)        (xi != 0)
    rate(z) = lambda_u * exp(-(z - u) / sigma)                         (xi = 0, the exponential tail)

and the level with a given rate is ``z = u + sigma / xi * ((rate / lambda_u) ** -xi - 1)`` (``u - sigma
ln(rate / lambda_u)`` for xi = 0). sigma and xi are estimated by probability-weighted moments (Hosking &
Wallis 1987: closed form, no optimizer, so the result does not depend on a solver's path); ``method =
"exponential"`` fixes xi = 0 (sigma = mean excess), which is conservative (higher levels) for the light,
bounded tails of a filtered residual. Below u the rate is counted directly in the log (no fit needed).

The uncertainty of a level is a bootstrap: the cluster count is redrawn from a Poisson law with the
observed mean, the excesses resampled with replacement, the tail refitted, the level recomputed;
the interval is the 5th-95th percentile over ``n_boot`` draws from a seeded generator.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
import numpy.typing as npt

from reflexarm.errors import ConfigError, DataError

__all__ = [
    "METHODS",
    "MIN_TAIL_CLUSTERS",
    "TAIL_CLUSTERS",
    "TAIL_QUANTILES",
    "TailFit",
    "cluster_maxima",
    "fit_tail",
]

#: Tail models: "gpd" (generalized Pareto, shape fitted) and "exponential" (shape 0).
METHODS = ("gpd", "exponential")
#: Fewest exceedance clusters above u a fit is made from: with fewer, the PWM estimate of the shape has a
#: standard error above ~0.2 (Hosking & Wallis 1987, Table 3 at n = 20), as large as the shapes that matter.
MIN_TAIL_CLUSTERS = 20
#: Clusters above u the fit uses: u is placed below the TAIL_CLUSTERS largest cluster maxima. Few enough that
#: the fit describes the top of the tail (a residual's largest excursions often come from another mechanism
#: than its bulk: a motion's reversal, a wrist joint's inertial coupling), enough for a stable shape (the
#: PWM shape's standard error is ~0.15 at n = 30, Hosking & Wallis 1987, Table 3).
TAIL_CLUSTERS = 30
#: Quantiles of |r| tried as the base level the clusters are first counted at, highest first: the highest
#: with at least MIN_TAIL_CLUSTERS clusters above it is used.
TAIL_QUANTILES = (0.999, 0.995, 0.99, 0.98, 0.95, 0.9, 0.8, 0.7, 0.5)
#: PWM estimates exist for xi < 1/2 only (the GPD's variance is finite); shapes are clipped to this range.
_XI_RANGE = (-1.0, 0.45)
_SECONDS_PER_HOUR = 3600.0


def cluster_maxima(x: npt.ArrayLike, level: float, gap: int) -> np.ndarray:
    """Maxima of the clusters of ``x > level``: exceedances at most ``gap`` samples apart form one cluster
    (``gap = 0``: each contiguous run of exceedances is one cluster). Returns the maxima in time order."""
    a = np.asarray(x, dtype=float).reshape(-1)
    idx = np.flatnonzero(a > level)
    if idx.size == 0:
        return np.zeros(0)
    breaks = np.flatnonzero(np.diff(idx) > gap + 1) + 1
    starts = np.r_[0, breaks]
    return np.maximum.reduceat(a[idx], starts)


def _pwm(excess: np.ndarray) -> tuple[float, float]:
    """(sigma, xi) of a GPD by probability-weighted moments (Hosking & Wallis 1987, eqs. 4-5)."""
    y = np.sort(excess)
    n = y.size
    a0 = float(y.mean())
    a1 = float(np.sum((n - np.arange(1, n + 1)) / (n - 1) * y) / n)
    denom = a0 - 2.0 * a1
    if not denom > 0.0 or not a0 > 0.0:  # all excesses equal (or zero): no spread to fit
        return max(a0, 1e-12), 0.0
    k = a0 / denom - 2.0  # Hosking's k = -xi
    xi = float(np.clip(-k, *_XI_RANGE))
    sigma = 2.0 * a0 * a1 / denom
    return float(max(sigma, 1e-12)), xi


def _fit(excess: np.ndarray, method: str) -> tuple[float, float]:
    if method == "exponential":
        return max(float(excess.mean()), 1e-12), 0.0
    return _pwm(excess)


def _level(u: float, rate_u: float, sigma: float, xi: float, rate: float) -> float:
    p = rate / rate_u
    if abs(xi) < 1e-9:
        return u - sigma * math.log(p)
    return u + sigma / xi * (p ** (-xi) - 1.0)


@dataclass(frozen=True)
class TailFit:
    """The fitted tail of one joint's |residual| (see the module docstring for the model).

    Attributes:
        u: fit threshold [Nm] (below the :data:`TAIL_CLUSTERS` largest cluster maxima).
        quantile: the fraction of the samples at or below u.
        rate_u: clusters above u per hour in the log [1/h].
        sigma: GPD scale [Nm]; xi: GPD shape [-] (0 for the exponential method).
        n_clusters: clusters above u; duration_h: the log's span [h]; gap_s: declustering gap [s].
        method: "gpd" or "exponential".
        excess: the cluster maxima above u minus u [Nm] (for the bootstrap).
        x_max: the largest |r| in the log [Nm].
        levels_below_u: levels [Nm] from 0 to u and the largest counted cluster rate at or above each
            [1/h], non-increasing (for the levels of rates above rate_u).
    """

    u: float
    quantile: float
    rate_u: float
    sigma: float
    xi: float
    n_clusters: int
    duration_h: float
    gap_s: float
    method: str
    excess: np.ndarray
    x_max: float
    levels_below_u: tuple[np.ndarray, np.ndarray]

    @property
    def endpoint(self) -> float:
        """Upper end of the fitted tail [Nm] (inf unless xi < 0)."""
        return self.u - self.sigma / self.xi if self.xi < 0 else math.inf

    def rate(self, z: float) -> float:
        """False alarms per hour at level ``z`` [Nm]: the fit above u, the counted rate below it."""
        if z >= self.u:
            t = 1.0 + self.xi * (z - self.u) / self.sigma
            if abs(self.xi) < 1e-9:
                return self.rate_u * math.exp(-(z - self.u) / self.sigma)
            return 0.0 if t <= 0.0 else self.rate_u * t ** (-1.0 / self.xi)
        lv, rates = self.levels_below_u
        return float(np.interp(z, lv, rates))

    def level(self, rate: float) -> float:
        """The level [Nm] whose false-alarm rate is ``rate`` [1/h]."""
        if not rate > 0.0:
            raise ConfigError(f"a false-alarm rate must be positive [1/h]; got {rate!r}")
        if rate <= self.rate_u:
            return _level(self.u, self.rate_u, self.sigma, self.xi, rate)
        lv, rates = self.levels_below_u  # rates fall as the level rises: interpolate on the reversed arrays
        return float(np.interp(rate, rates[::-1], lv[::-1]))

    def level_interval(self, rate: float, *, n_boot: int = 200, seed: int = 0) -> tuple[float, float]:
        """5th-95th percentile of :meth:`level` over a Poisson/resampling bootstrap (module docstring).

        Below u (a counted level) the interval is the counted levels at the rates of a Poisson count's
        5 % and 95 % quantiles.
        """
        if rate > self.rate_u:
            from scipy.stats import poisson

            n = rate * self.duration_h
            lo_n, hi_n = poisson.ppf(0.05, n), poisson.ppf(0.95, n)
            lo_r, hi_r = max(lo_n, 0.5) / self.duration_h, max(hi_n, 0.5) / self.duration_h
            return self.level(hi_r), self.level(lo_r)
        rng = np.random.default_rng(seed)
        levels = np.empty(n_boot)
        for b in range(n_boot):
            m = int(rng.poisson(self.n_clusters))
            if m < 2:
                levels[b] = self.u
                continue
            ex = rng.choice(self.excess, size=m, replace=True)
            sigma, xi = _fit(ex, self.method)
            rate_u = m / self.duration_h
            levels[b] = _level(self.u, rate_u, sigma, xi, min(rate, rate_u))
        lo, hi = np.percentile(levels, [5.0, 95.0])
        return float(lo), float(hi)

    def as_dict(self) -> dict[str, object]:
        """JSON-ready description of the fit."""
        return {
            "method": self.method,
            "u_Nm": self.u,
            "u_quantile": self.quantile,
            "clusters_above_u": self.n_clusters,
            "rate_above_u_per_h": self.rate_u,
            "sigma_Nm": self.sigma,
            "xi": self.xi,
            "endpoint_Nm": None if math.isinf(self.endpoint) else self.endpoint,
            "max_abs_residual_Nm": self.x_max,
            "gap_s": self.gap_s,
        }


def fit_tail(
    x: npt.ArrayLike | list[np.ndarray],
    dt: float,
    *,
    gap_s: float,
    method: str = "gpd",
    min_clusters: int = MIN_TAIL_CLUSTERS,
    tail_clusters: int = TAIL_CLUSTERS,
) -> TailFit:
    """Fit the tail of the cluster maxima of ``x`` (|residual| of one joint, samples ``dt`` s apart).

    ``x`` may be a list of arrays (several logs): clusters are counted in each and pooled, the durations
    added. The clusters are first counted above the highest of :data:`TAIL_QUANTILES` of the pooled samples
    with at least ``min_clusters`` clusters above it; u is then placed between the ``tail_clusters``-th and
    the next largest cluster maximum (when there are more), so the fit sees the top of the tail.

    Raises:
        ConfigError: unknown method, non-positive dt or negative gap.
        DataError: fewer than ``min_clusters`` clusters above every candidate u (a log too short or too
            quiet to fit a tail; the message gives the count found).
    """
    if method not in METHODS:
        raise ConfigError(f"unknown tail method {method!r}; choose one of: {', '.join(METHODS)}")
    if not (math.isfinite(dt) and dt > 0.0):
        raise ConfigError(f"dt must be a positive period [s]; got {dt!r}")
    if not (math.isfinite(gap_s) and gap_s >= 0.0):
        raise ConfigError(f"gap_s must be a non-negative time [s]; got {gap_s!r}")
    parts = [np.abs(np.asarray(p, dtype=float).reshape(-1)) for p in (x if isinstance(x, list) else [x])]
    pooled = np.concatenate(parts)
    if pooled.size < 2 or not np.all(np.isfinite(pooled)):
        bad = int((~np.isfinite(pooled)).sum())
        raise DataError(f"a tail fit needs at least 2 finite samples; got {pooled.size} samples ({bad} NaN/inf)")
    gap = int(math.ceil(gap_s / dt - 1e-9))
    duration_h = sum(p.size for p in parts) * dt / _SECONDS_PER_HOUR
    qu, u, m = _threshold(parts, pooled, gap, gap_s, min_clusters, tail_clusters)
    excess = m - u
    sigma, xi = _fit(excess, method)
    lv, rates = _rates_below(parts, gap, u, m.size, duration_h)
    return TailFit(
        u=u,
        quantile=qu,
        rate_u=m.size / duration_h,
        sigma=sigma,
        xi=xi,
        n_clusters=int(m.size),
        duration_h=duration_h,
        gap_s=float(gap_s),
        method=method,
        excess=excess,
        x_max=float(pooled.max()),
        levels_below_u=(lv, rates),
    )


def _pooled_maxima(parts: list[np.ndarray], level: float, gap: int) -> np.ndarray:
    """The cluster maxima above ``level`` of every part, pooled."""
    return np.concatenate([cluster_maxima(p, level, gap) for p in parts])


def _threshold(
    parts: list[np.ndarray], pooled: np.ndarray, gap: int, gap_s: float, min_clusters: int, tail_clusters: int
) -> tuple[float, float, np.ndarray]:
    """(the quantile of u in the pooled samples, u, the cluster maxima above u): the highest of
    :data:`TAIL_QUANTILES` with ``min_clusters`` clusters above it, then u moved up to just below the
    ``tail_clusters`` largest maxima; fewer clusters above every candidate is a DataError (``gap_s`` for it)."""
    best: tuple[float, float, np.ndarray] | None = None
    counts = []
    for qu in TAIL_QUANTILES:
        u = float(np.quantile(pooled, qu))
        m = _pooled_maxima(parts, u, gap)
        counts.append((qu, m.size))
        if m.size >= min_clusters:
            best = (qu, u, m)
            break
    if best is None:
        found = ", ".join(f"{c} above the {100 * q:g} %" for q, c in counts)
        raise DataError(
            f"too few separate excursions of |residual| to fit a tail: need {min_clusters} clusters above the "
            f"fit threshold; found {found} quantile (a longer log, more varied motion, or a shorter gap_s={gap_s:g} s)"
        )
    qu, u, m = best
    if m.size > tail_clusters:
        top = np.sort(m)[::-1]
        u = float(0.5 * (top[tail_clusters - 1] + top[tail_clusters]))
        m = _pooled_maxima(parts, u, gap)
        qu = float(np.mean(pooled <= u))
    return qu, u, m


def _rates_below(
    parts: list[np.ndarray], gap: int, u: float, n_clusters: int, duration_h: float
) -> tuple[np.ndarray, np.ndarray]:
    """(101 levels from 0 to u, the rate [1/h] of each), counted cluster rates below u, for levels that a
    rate above lambda_u asks for (interpolation). At low levels the excursions merge into few long ones,
    so the counted rate rises and then falls with the level; the rate of a level is taken as the largest
    counted rate at or above it."""
    lv = np.linspace(0.0, u, 101)
    counted = np.array([_pooled_maxima(parts, v, gap).size for v in lv], dtype=float) / duration_h
    rates = np.maximum.accumulate(np.r_[counted, n_clusters / duration_h][::-1])[::-1][:-1]
    return lv, rates
