"""The survival rule of a pushed run (pure: it judges a finished ``RunResult``, it runs nothing).

A pushed run survives when it does not fall until ``SURVIVAL_STEPS`` impacts after the end of the push,
and at the end of the run p is within ``P_TOL`` [m] of its reference and tau' within ``TAU_DOT_TOL`` of 1
(the robot is back on its preferred gait). The p reference is p_d, or under model error (a plant whose
masses, centres of mass or inertias differ from the controller's description) the p of the unpushed walk
with the same settings at the same instant (``trials.p_reference``): on MuJoCo with the inertias 30 %
larger the unpushed robot walks with p 1.2-1.4 mm short of p_d after 11 steps. With noisy or quantised
sensors tau' is compared with the band ``TAU_DOT_TOL_NOISE`` instead: the controller's tau' follows its
estimate of the state and never settles exactly (an undisturbed walk under the design-point noise leaves
1 by up to 0.018, docs/robustness.md), so a pushed robot is back when it is as close to the gait as an
unpushed one under the same noise.
"""
from __future__ import annotations

from dataclasses import replace

from biped_controller.studies.runner import RunResult
from biped_controller.studies.trial.context import context
from biped_controller.studies.trial.settings import RunSettings

SURVIVAL_STEPS = 10             # impacts that must follow the end of the push
P_TOL = 1e-3                    # |p - p_ref| at the end of a survived run [m]
TAU_DOT_TOL = 1e-3              # |tau' - 1| at the end of a survived run [-]
TAU_DOT_TOL_NOISE = 0.02        # |tau' - 1| at the end of a survived run with noisy sensors [-]


def noisy_sensing(settings: RunSettings) -> bool:
    """The run's sensors are noisy or quantised (survival then uses the noise band for tau')."""
    p = settings.perturbation
    return p is not None and bool(p.noise_q or p.noise_qd or p.encoder_bits or p.noise_pitch)


def model_error(settings: RunSettings) -> bool:
    """The run's plant differs from the controller's description in its masses, centres of mass or inertias
    (friction, sensing and delay are not model error here)."""
    p = settings.perturbation
    return p is not None and not replace(p, mu=None).model_is_nominal


def survival(result: RunResult, push_end: float, steps_after: int = SURVIVAL_STEPS, noisy: bool = False,
             p_ref: float | None = None) -> tuple[bool, str]:
    """(survived, reason) by the rule of the module docstring for a push that ended at ``push_end`` [s]
    (``noisy``: the band for noisy sensors; ``p_ref`` [m]: the unpushed walk's p under model error, None:
    p_d)."""
    fam = context().family
    tau_tol = TAU_DOT_TOL_NOISE if noisy else TAU_DOT_TOL
    if result.fallen:
        return False, f"fell: {result.fall_cause} at t = {result.fall_time:.4f} s"
    after = sum(1 for i in result.impacts if i.t >= push_end)
    if after < steps_after:
        return False, f"only {after} steps after the push (time limit)"
    last = result.statuses[-1]
    if p_ref is not None:
        if not abs(last.p - p_ref) <= P_TOL:
            return False, f"p = {last.p:.5f} m not back to the unpushed walk's {p_ref:.5f} m (> {P_TOL})"
    elif abs(last.p - fam.p_d) > P_TOL:
        return False, f"p = {last.p:.5f} m not back to p_d (|p - p_d| > {P_TOL})"
    if abs(last.tau_dot - 1.0) > tau_tol:
        return False, f"tau' = {last.tau_dot:.5f} not back to 1 (> {tau_tol})"
    return True, "survived"


def rule_text(noisy: bool = False, p_reference: float | None = None) -> str:
    """The rule in words, with its tolerances (for tables)."""
    p = (f"|p - p_d| <= {P_TOL} m" if p_reference is None
         else f"|p - p_ref| <= {P_TOL} m (p_ref = {p_reference:.5f} m: the unpushed walk's, model error)")
    tau = (f"|tau' - 1| <= {TAU_DOT_TOL_NOISE} at the end, the band for noisy sensors" if noisy
           else f"|tau' - 1| <= {TAU_DOT_TOL} at the end")
    return f"no fall for {SURVIVAL_STEPS} steps after the push, {p} and {tau}"
