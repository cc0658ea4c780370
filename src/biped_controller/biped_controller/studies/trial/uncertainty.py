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

Difference of two survival rates (controllers A and B at one force). On common seeds (the same seed
index i runs both; a pair counts when both trials count) the pairs give the 2 x 2 table a (both survive),
b (A only), c (B only), d (neither), n = a + b + c + d, and theta^ = p^_A - p^_B = (b - c) / n. Interval:
Newcombe's hybrid score interval for paired data (Newcombe 1998, Stat. Med. 17:2635, method 10): with
the Wilson intervals (l1, u1) of p^_A = (a + b) / n and (l2, u2) of p^_B = (a + c) / n and the
correlation phi^ = N / sqrt((a + b)(c + d)(a + c)(b + d)), N = a d - b c, lowered to max(N - n / 2, 0)
when N > 0 (0 when a margin is empty),

    delta   = sqrt((p^_A - l1)^2 - 2 phi^ (p^_A - l1)(u2 - p^_B) + (u2 - p^_B)^2)
    epsilon = sqrt((u1 - p^_A)^2 - 2 phi^ (u1 - p^_A)(p^_B - l2) + (p^_B - l2)^2)
    [theta^ - delta, theta^ + epsilon].

For independent samples (different seeds) phi^ = 0 and the margins are k1 / n1, k2 / n2 (Newcombe 1998,
Stat. Med. 17:873, method 10). Common seeds remove the noise both controllers share: the interval is
narrower when the outcomes correlate (phi^ > 0).

Seed of a trial: ``trial_seed(cell, index)`` = the first 8 bytes of SHA-256 over the cell's canonical JSON
(sorted keys) and the index, big-endian, masked to 63 bits (a non-negative int64, a valid
``PlantPerturbation.seed``). The cell names what the trial's draws may depend on (plant, profile, push onset,
duration, direction, height); neither the force nor the controller is in it, so a seed index is the same
noise sequence at every force of a cell and for every controller (common random numbers along the force
axis and across controllers: the paired comparison above).

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


def paired_difference(a: int, b: int, c: int, d: int, z: float = Z95) -> dict:
    """p^_A - p^_B on common seeds and its Newcombe hybrid score interval (module docstring): ``a`` pairs
    where both survive, ``b`` A only, ``c`` B only, ``d`` neither; a + b + c + d >= 1."""
    counts = (a, b, c, d)
    if any(isinstance(x, bool) or int(x) != x or x < 0 for x in counts) or sum(counts) < 1:
        raise UncertaintyError(f"the paired counts must be integers >= 0 with a positive sum, got {counts!r}")
    a, b, c, d = (int(x) for x in counts)
    n = a + b + c + d
    pa, pb = (a + b) / n, (a + c) / n
    l1, u1 = wilson(a + b, n, z)
    l2, u2 = wilson(a + c, n, z)
    margins = (a + b) * (c + d) * (a + c) * (b + d)
    num = a * d - b * c
    if num > 0:
        num = max(num - n / 2.0, 0.0)
    phi = 0.0 if margins == 0 else num / math.sqrt(margins)
    delta = math.sqrt(max((pa - l1) ** 2 - 2.0 * phi * (pa - l1) * (u2 - pb) + (u2 - pb) ** 2, 0.0))
    eps = math.sqrt(max((u1 - pa) ** 2 - 2.0 * phi * (u1 - pa) * (pb - l2) + (pb - l2) ** 2, 0.0))
    theta = (b - c) / n
    return {"pairs": n, "both": a, "a_only": b, "b_only": c, "neither": d, "rate_a": pa, "rate_b": pb,
            "difference": theta, "lo": max(-1.0, theta - delta), "hi": min(1.0, theta + eps), "phi": phi}


def independent_difference(k1: int, n1: int, k2: int, n2: int, z: float = Z95) -> tuple[float, float, float]:
    """k1 / n1 - k2 / n2 of independent samples and its Newcombe hybrid score interval (module docstring):
    (difference, lo, hi)."""
    l1, u1 = wilson(k1, n1, z)
    l2, u2 = wilson(k2, n2, z)
    p1, p2 = k1 / n1, k2 / n2
    return (p1 - p2, p1 - p2 - math.hypot(p1 - l1, u2 - p2), p1 - p2 + math.hypot(u1 - p1, p2 - l2))


#: the name of the comparison's interval, stored beside the numbers
DIFFERENCE_INTERVAL = ("Newcombe hybrid score interval for paired data (Stat. Med. 17:2635, 1998, method 10) on "
                       "common seeds: the Wilson limits of both rates combined with their correlation")


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
