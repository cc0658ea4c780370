"""The survival rule of a pushed run: the one rule of every study, on both plants and every profile.

A pushed run *survives* when

1. it does not fall (the plant's own fall definition: ``RunResult.fallen``) until ``SURVIVAL_STEPS``
   impacts after the end of the push, and
2. at the end of the run it is back on the preferred gait: |p - p_d| <= ``band.p_tol`` [m] and
   |tau' - 1| <= ``band.tau_dot_tol`` [-], on the controller's last decided p and tau'.

The *band* is the one of the same plant, profile, settings, mode and perturbation without the push: the
unpushed walk of the same number of impacts is run once, and over its last ``band_window`` steps (every
control period from impact N - W to the end, N the trial's impacts) its excursions e_p = max |p - p_d| and
e_tau = max |tau' - 1| are taken; then

    p_tol = max(P_FLOOR, k e_p),   tau_dot_tol = max(TAU_DOT_FLOOR, k e_tau)

with k = ``band_factor`` and W = ``band_window`` from ``config/studies.yaml`` (argued there). The floors,
1 mm and 1e-3, are the strict rule's tolerances: a band is never tighter. Where the unpushed walk settles
exactly (the rigid plant, ideal sensors, nominal model) the band is the floors and the rule is the strict
one; under sensor noise, model error (p settles off p_d) or MuJoCo's contact the band is as wide as the
unpushed robot's own wander, so none of them needs a rule of its own. When the unpushed walk itself falls,
no band can be measured and the floors are used (``Band.unpushed_fall`` says so).

A run that does not fall but is not back within the band *survived without settling*: ``Verdict.fell``
False, ``Verdict.survived`` False. The *no-fall edge* of a search counts such runs as not fallen; the
*survival boundary* counts them as failures (``trial.search``).

The early stop (:mod:`.stop`) declares a trial survived only with p and tau' inside half the floors (the
rigid plant) or half the trial's own band (MuJoCo), hence inside the band.
"""
from __future__ import annotations

import functools
import math
import os
from dataclasses import dataclass, replace
from pathlib import Path

from biped_model.settings import default_config_dir, read_settings

from biped_controller.closed_loop.runner import RunResult
from biped_controller.studies.trial.context import context
from biped_controller.studies.trial.stop import StudySettingsError

SURVIVAL_STEPS = 10             # impacts that must follow the end of the push
P_FLOOR = 1e-3                  # the band's smallest |p - p_d| at the end of a survived run [m]
TAU_DOT_FLOOR = 1e-3            # the band's smallest |tau' - 1| at the end of a survived run [-]

# the names the studies used before the band (the floors are those tolerances)
P_TOL = P_FLOOR
TAU_DOT_TOL = TAU_DOT_FLOOR


class SurvivalSettingsError(StudySettingsError):
    """``config/studies.yaml``'s survival band settings are out of range (the message names the key)."""


@dataclass(frozen=True)
class Band:
    """The end tolerances of a survival trial: |p - p_d| <= ``p_tol`` [m], |tau' - 1| <= ``tau_dot_tol``;
    ``p_excursion`` [m] and ``tau_dot_excursion`` the unpushed walk's over the window (NaN when it fell);
    ``unpushed_fall`` the unpushed walk's fall ("" when it walked); ``unpushed_fault`` the controller fault
    that ended the unpushed walk ("" without one: only a plug-in controller faults); ``checks_p``,
    ``checks_tau_dot``: the controller reports p, tau' (the adaptive controller always does; a plug-in
    that reports neither is judged by the fall and the step count alone, and the rule's text says so)."""

    p_tol: float
    tau_dot_tol: float
    p_excursion: float
    tau_dot_excursion: float
    unpushed_fall: str = ""
    unpushed_fault: str = ""
    checks_p: bool = True
    checks_tau_dot: bool = True

    @property
    def is_floor(self) -> bool:
        """The band is the floors (the strict rule)."""
        return self.p_tol == P_FLOOR and self.tau_dot_tol == TAU_DOT_FLOOR

    def as_dict(self) -> dict:
        """JSON-ready; ``unpushed_fault`` and ``checks`` (which of p and tau_dot are checked) only where they
        differ from a walk without a fault and a controller that reports both."""
        def f(x):
            return None if not math.isfinite(x) else float(x)
        out = {"p_tol": self.p_tol, "tau_dot_tol": self.tau_dot_tol, "p_excursion": f(self.p_excursion),
               "tau_dot_excursion": f(self.tau_dot_excursion), "unpushed_fall": self.unpushed_fall}
        if self.unpushed_fault:
            out["unpushed_fault"] = self.unpushed_fault
        if not (self.checks_p and self.checks_tau_dot):
            out["checks"] = [k for k, on in (("p", self.checks_p), ("tau_dot", self.checks_tau_dot)) if on]
        return out


FLOOR_BAND = Band(P_FLOOR, TAU_DOT_FLOOR, math.nan, math.nan)


@dataclass(frozen=True)
class Verdict:
    """A survival trial's outcome: ``survived`` (rule met), ``fell`` (the plant's fall before the run's
    end), ``reason`` in words ("survived", "fell: ...", "only N steps ...", "p = ... not back ...",
    "tau' = ... not back ...")."""

    survived: bool
    fell: bool
    reason: str


@dataclass(frozen=True)
class SurvivalRule:
    """The rule of the module docstring: ``steps`` impacts after the push, the band's factor k
    (``band_factor``) and window W [steps] (``band_window``)."""

    steps: int
    band_factor: float
    band_window: int

    KEYS = ("survival_band_factor", "survival_band_window")

    @classmethod
    def load(cls, path: str | os.PathLike | None = None) -> "SurvivalRule":
        """The rule with ``config/studies.yaml``'s band settings (``path``: another file); a value out of
        range raises :class:`SurvivalSettingsError` naming the key."""
        p = Path(path) if path is not None else default_config_dir() / "studies.yaml"
        v = read_settings(p, cls.KEYS)
        return cls.of(v["survival_band_factor"], v["survival_band_window"], source=str(p))

    @classmethod
    def of(cls, band_factor: object, band_window: object, source: str = "survival rule") -> "SurvivalRule":
        """The rule with these band settings, checked: k a finite number >= 1 (a band narrower than the
        unpushed walk's own excursion would fail the unpushed walk), W an integer in [1, SURVIVAL_STEPS]."""
        k, w = band_factor, band_window
        if isinstance(k, bool) or not isinstance(k, (int, float)) or not (math.isfinite(k) and k >= 1.0):
            raise SurvivalSettingsError(f"{source}: 'survival_band_factor' must be a finite number >= 1, got {k!r}")
        if isinstance(w, bool) or not isinstance(w, int) or not 1 <= w <= SURVIVAL_STEPS:
            raise SurvivalSettingsError(
                f"{source}: 'survival_band_window' must be an integer in [1, {SURVIVAL_STEPS}], got {w!r}")
        return cls(SURVIVAL_STEPS, float(k), int(w))

    def identity(self) -> dict:
        """JSON-ready: what the rule's verdicts depend on besides the band's unpushed walk."""
        return {"steps": self.steps, "p_floor": P_FLOOR, "tau_dot_floor": TAU_DOT_FLOOR,
                "band_factor": self.band_factor, "band_window": self.band_window}

    # ------------------------------------------------------------------------------------------ band
    def band_from_walk(self, walk: RunResult) -> Band:
        """The band of an unpushed walk (records kept): the floors or k times its excursion over the last
        ``band_window`` steps, whichever is wider."""
        if walk.fallen:
            return replace(FLOOR_BAND, unpushed_fall=f"{walk.fall_cause} at t = {walk.fall_time:.4f} s")
        t0 = self.window_start(walk.impacts)
        win = [s for s in walk.statuses if s.t >= t0]
        return self.band_from_series([s.p for s in win], [s.tau_dot for s in win])

    def window_start(self, impacts) -> float:
        """[s] the start of the band's window: the impact ``band_window`` steps before the last one (-inf
        when the walk has fewer)."""
        return impacts[len(impacts) - self.band_window - 1].t if len(impacts) > self.band_window else -math.inf

    def band_from_series(self, p, tau_dot) -> Band:
        """The band of an unpushed walk's p [m] and tau' [-] over the window (either may be empty: a
        controller that reports no p or tau' has no excursion of it)."""
        p_d = context().family.p_d
        e_p = max((abs(x - p_d) for x in p), default=0.0)
        e_tau = max((abs(x - 1.0) for x in tau_dot), default=0.0)
        return Band(max(P_FLOOR, self.band_factor * e_p), max(TAU_DOT_FLOOR, self.band_factor * e_tau), e_p, e_tau)

    # ------------------------------------------------------------------------------------------ verdict
    def verdict(self, result: RunResult, push_end: float, band: Band = FLOOR_BAND) -> Verdict:
        """The verdict on ``result``, a run pushed until ``push_end`` [s], with ``band``."""
        last = result.statuses[-1] if result.statuses else None
        fall = f"{result.fall_cause} at t = {result.fall_time:.4f} s" if result.fallen else ""
        return self.judge(result.fallen, fall, result.impacts,
                          push_end, None if last is None else last.p, None if last is None else last.tau_dot, band)

    def judge(self, fallen: bool, fall: str, impacts, push_end: float, p: float | None, tau_dot: float | None,
              band: Band = FLOOR_BAND) -> Verdict:
        """The verdict from a run's outcome: ``fallen`` and its description ``fall``, its impacts, the push's
        end [s], the controller's last p [m] and tau' [-] (None: not reported, not checked) and ``band``."""
        if fallen:
            return Verdict(False, True, f"fell: {fall}")
        after = sum(1 for i in impacts if i.t >= push_end)
        if after < self.steps:
            return Verdict(False, False, f"only {after} steps after the push (time limit)")
        p_d = context().family.p_d
        if p is not None and not abs(p - p_d) <= band.p_tol:
            return Verdict(False, False, f"p = {p:.5f} m not back to p_d (|p - p_d| > {band.p_tol:.3g} m)")
        if tau_dot is not None and not abs(tau_dot - 1.0) <= band.tau_dot_tol:
            return Verdict(False, False, f"tau' = {tau_dot:.5f} not back to 1 (> {band.tau_dot_tol:.3g})")
        return Verdict(True, False, "survived")

    def text(self, band: Band | None = None) -> str:
        """The rule in words, with a trial's band (None: the band's definition). The end tolerances are
        stated only for what the controller reports (``Band.checks_p``, ``Band.checks_tau_dot``); an unpushed
        walk that ended in a controller fault is called a fault, not a fall."""
        head = f"no fall for {self.steps} steps after the push"
        if band is None:
            return (head + f", then |p - p_d| <= max({P_FLOOR:g} m, {self.band_factor:g} e_p) and |tau' - 1| <= "
                    f"max({TAU_DOT_FLOOR:g}, {self.band_factor:g} e_tau), e = the unpushed walk's largest "
                    f"excursion over its last {self.band_window} steps")
        src = ("the floors: the unpushed walk faulted (" + band.unpushed_fault + ")" if band.unpushed_fault
               else "the floors: the unpushed walk fell (" + band.unpushed_fall + ")" if band.unpushed_fall
               else "the floors" if band.is_floor
               else f"{self.band_factor:g} x the unpushed walk's excursion over its last {self.band_window} steps")
        ends = ([f"|p - p_d| <= {band.p_tol:.3g} m"] if band.checks_p else []) + \
               ([f"|tau' - 1| <= {band.tau_dot_tol:.3g}"] if band.checks_tau_dot else [])
        if not ends:
            why = "; the unpushed walk faulted (" + band.unpushed_fault + ")" if band.unpushed_fault else ""
            return head + f" (the controller reports neither p nor tau': no return to the gait is checked{why})"
        unreported = ("" if len(ends) == 2 else
                      " (the controller does not report " + ("tau'" if band.checks_p else "p") + ": not checked)")
        return head + ", then " + " and ".join(ends) + f" ({src})" + unreported


@functools.lru_cache(maxsize=4)
def _rule(stamp: int) -> SurvivalRule:
    return SurvivalRule.load()


def survival_rule() -> SurvivalRule:
    """``config/studies.yaml``'s survival rule, read again whenever the file changed."""
    return _rule(os.stat(default_config_dir() / "studies.yaml").st_mtime_ns)


def survival(result: RunResult, push_end: float, band: Band = FLOOR_BAND) -> tuple[bool, str]:
    """(survived, reason): :meth:`SurvivalRule.verdict` of this process's rule."""
    v = survival_rule().verdict(result, push_end, band)
    return v.survived, v.reason


def rule_text(band: Band | None = None) -> str:
    """:meth:`SurvivalRule.text` of this process's rule."""
    return survival_rule().text(band)
