"""The early stop in mode lambda: a trial whose torso offset is not back at 0 one period after the first
impact after the push is not stopped as a survival. (The capability map's read-back, once
``studies/torso.map_comparison``, is ``lab.torso_compare``: its tests are ``lab/tests/test_torso_compare.py``.)"""
from __future__ import annotations


def test_early_stop_sees_the_torso_offset(monkeypatch):
    """Mode lambda, 71.875 N forward for 25 ms at phase 0.9: one period after the first impact after the push
    p, tau' and the plant's (q, q') are on the gait (phi vanishes at the impact, p and tau' never leave x* in
    mode lambda) but lambda is not back at 0, and the full trial falls at the next touchdown. The early stop
    gives the full trial's outcome; negative control: with the lambda tolerances unbounded it would report
    the trial survived."""
    import math
    from biped_controller.studies.trial import context as tcontext
    from biped_controller.studies.trial import runs, stop, trials
    from biped_controller.studies.trial import settings as ts
    T = tcontext.context().family.T
    args = (runs.paper_push(71.875, start=0.9 * T, duration=0.025), "lambda")
    full = trials.survives(*args, settings=ts.RunSettings(full_trials=True), pool=False)
    stopped = trials.survives(*args, pool=False)
    assert not full["survived"] and full["fall_cause"] == "tip_heel"
    assert (stopped["survived"], stopped["reason"], stopped["fall_time"]) == \
           (full["survived"], full["reason"], full["fall_time"])
    es = stop.early_stop()
    loose = stop.EarlyStop(es.enabled, es.q, es.qd, es.p, es.p_dot, es.tau_dot, es.force, math.inf, math.inf)
    monkeypatch.setattr(stop, "early_stop", lambda: loose)
    assert trials.survives(*args, pool=False)["survived"]
