"""Survival as a probability over seeds: the Wilson score interval, the seed of a trial, and the adaptive
search for the forces at which survival crosses a level (pure: no simulation here).

Wilson score interval (Wilson 1927, JASA 22:209; Newcombe 1998, Stat. Med. 17:857, method 3). For k
successes in n Bernoulli trials, p^ = k / n, the 95 % interval is the set of p whose score test
|p^ - p| <= z sqrt(p (1 - p) / n) accepts, z = 1.959963984540054 (the standard normal's 97.5 % quantile).
Solving the quadratic in p:

    centre = (p^ + z^2 / (2 n)) / (1 + z^2 / n)
    half   = z / (1 + z^2 / n) * sqrt(p^ (1 - p^) / n + z^2 / (4 n^2))
    [lo, hi] = [centre - half, centre + half]

always inside [0, 1]; k = 0 gives lo = 0 exactly and k = n gives hi = 1 exactly (set so, the closed form
gives them up to rounding).

Seed of a trial: ``trial_seed(cell, index)`` = the first 8 bytes of SHA-256 over the cell's canonical JSON
(sorted keys) and the index, big-endian, masked to 63 bits (a non-negative int64, a valid
``PlantPerturbation.seed``). The cell names what the trial's draws may depend on (plant, profile, mode,
push onset, duration, direction, height); the force is not in it, so a seed index is the same noise
sequence at every force of a cell (common random numbers along the force axis).

Crossing search (:func:`crossing_search`): survival s(F) at force F is estimated by the rate k / n of a
complete batch of the n seeds; for a level c in (0, 1) the crossing F_c is where s falls through c. The
search takes a bracket [lo, hi] with rate(lo) >= c > rate(hi) (from the coarse batches) and bisects it
on batch rates (noisy bisection: the midpoint's batch decides the side, rate >= c -> lo) until
hi - lo <= resolution; estimator F^_c = (lo + hi) / 2. Interval: every force tried whose Wilson interval
lies wholly above c (below the estimate) or wholly below c (above it) bounds the crossing, if s decreases
in F: [the largest force below F^_c whose Wilson lower limit exceeds c, the smallest force above F^_c
whose Wilson upper limit is below c]; None where no force tried excludes c on that side. Each decision
uses a complete batch, so the answer does not depend on how the trials were scheduled.
"""
from __future__ import annotations

import hashlib
import json
import math
from typing import Callable, Mapping

#: the standard normal's 97.5 % quantile: the two-sided 95 % interval's z
Z95 = 1.959963984540054

#: the crossing levels the max-push table reports by default
DEFAULT_LEVELS = (0.9, 0.5)

#: the names of the estimator and the interval method, as stored beside the numbers
ESTIMATOR = "noisy bisection on complete batches of seeds: midpoint of the final bracket"
INTERVAL = ("Wilson score 95 % per force; crossing interval: nearest forces tried whose Wilson interval "
            "excludes the level")

_MASK63 = (1 << 63) - 1


class UncertaintyError(ValueError):
    """A bad count, level or resolution (the message names it)."""


def wilson(k: int, n: int, z: float = Z95) -> tuple[float, float]:
    """The Wilson score interval (module docstring) for ``k`` successes in ``n`` trials, 0 <= k <= n, n >= 1."""
    if isinstance(k, bool) or isinstance(n, bool) or int(k) != k or int(n) != n:
        raise UncertaintyError(f"k and n must be integers, got k={k!r}, n={n!r}")
    k, n = int(k), int(n)
    if n < 1 or not 0 <= k <= n:
        raise UncertaintyError(f"need 0 <= k <= n and n >= 1, got k={k}, n={n}")
    if not (math.isfinite(z) and z > 0.0):
        raise UncertaintyError(f"z must be a finite number > 0, got {z!r}")
    p = k / n
    z2 = z * z
    denom = 1.0 + z2 / n
    centre = (p + z2 / (2.0 * n)) / denom
    half = z / denom * math.sqrt(p * (1.0 - p) / n + z2 / (4.0 * n * n))
    lo = 0.0 if k == 0 else max(0.0, centre - half)
    hi = 1.0 if k == n else min(1.0, centre + half)
    return lo, hi


def trial_seed(cell: Mapping, index: int) -> int:
    """The seed of seed index ``index`` (>= 0) of ``cell`` (a JSON-ready mapping): module docstring."""
    if isinstance(index, bool) or int(index) != index or index < 0:
        raise UncertaintyError(f"seed index must be an integer >= 0, got {index!r}")
    text = json.dumps({"cell": dict(cell), "index": int(index)}, sort_keys=True, separators=(",", ":"))
    return int.from_bytes(hashlib.sha256(text.encode("utf-8")).digest()[:8], "big") & _MASK63


def check_level(level: float) -> float:
    """A crossing level strictly inside (0, 1)."""
    if not (isinstance(level, (int, float)) and math.isfinite(level) and 0.0 < level < 1.0):
        raise UncertaintyError(f"a crossing level must lie in (0, 1), got {level!r}")
    return float(level)


def rate_row(force: float, k: int, n: int, excluded: int = 0) -> dict:
    """One force's survival rate: k survivals of n counted seeds, its Wilson interval; ``excluded``: seeds
    counted apart (their unpushed walk fell, or the controller faulted), in no rate."""
    lo, hi = wilson(k, n) if n else (None, None)
    return {"force": force, "survived": k, "counted": n, "excluded": excluded,
            "rate": (k / n) if n else None, "wilson_lo": lo, "wilson_hi": hi}


def crossing_interval(rates: Mapping[float, tuple[int, int]], level: float, estimate: float) -> tuple[float | None, float | None]:
    """The crossing's interval from every force tried (force -> (k, n)): module docstring."""
    lo = hi = None
    for f, (k, n) in rates.items():
        if n < 1:
            continue
        wl, wh = wilson(k, n)
        if f <= estimate and wl > level and (lo is None or f > lo):
            lo = f
        if f >= estimate and wh < level and (hi is None or f < hi):
            hi = f
    return lo, hi


def crossing_search(batch: Callable[[float], tuple[int, int]], level: float, lo: float, hi: float,
                    resolution: float, rates: dict[float, tuple[int, int]] | None = None) -> dict:
    """Bisect [lo, hi] [N] (rate(lo) >= ``level`` > rate(hi)) on complete batches to ``resolution``
    [N]: ``batch(force)`` runs every seed at ``force`` and returns (survivals, counted seeds). ``rates``:
    batches already run, by force (reused; new ones added). A midpoint with no counted seed ends the
    search there (nothing to decide on). Returns level, bracket, estimate, interval, forces tried here."""
    check_level(level)
    if not (math.isfinite(resolution) and resolution > 0.0):
        raise UncertaintyError(f"the resolution must be a number > 0, got {resolution!r}")
    rates = {} if rates is None else rates
    tried = []
    while hi - lo > resolution:
        mid = 0.5 * (lo + hi)
        if mid not in rates:
            rates[mid] = tuple(batch(mid))
            tried.append(mid)
        k, n = rates[mid]
        if n < 1:
            break
        if k / n >= level:
            lo = mid
        else:
            hi = mid
    est = 0.5 * (lo + hi)
    ilo, ihi = crossing_interval(rates, level, est)
    return {"level": level, "bracket": [lo, hi], "estimate": est, "interval": [ilo, ihi], "tried": tried}


def first_bracket(rates: Mapping[float, tuple[int, int]], level: float, floor: float = 0.0) -> tuple[float, float | None]:
    """From coarse batches (force -> (k, n), ascending scan): the first force whose rate is below ``level``
    and the force before it (``floor`` when it is the first); (last force, None) when none is below."""
    prev = floor
    for f in sorted(rates):
        k, n = rates[f]
        if n >= 1 and k / n < level:
            return prev, f
        prev = f
    return prev, None
