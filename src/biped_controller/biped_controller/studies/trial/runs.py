"""One closed-loop run with a run's settings (``runner.run``: plant + AdaptiveController in lockstep, no
ROS), the paper's push and the pushed run of a survival trial."""
from __future__ import annotations

import functools
import math

from biped_sim.plant.push import Push

from biped_controller.closed_loop import runner
from biped_controller.closed_loop.runner import RunResult
from biped_controller.studies.trial.context import context
from biped_controller.studies.trial.settings import DEFAULT_SETTINGS, RunSettings
from biped_controller.studies.trial.survival import SURVIVAL_STEPS

DEFAULT_START = 0.2315          # [s] the middle of the first step (T / 2 = 0.2315 s)
DEFAULT_DURATION = 0.025        # [s] the paper's push duration


def paper_push(force: float, *, start: float = DEFAULT_START, duration: float = DEFAULT_DURATION,
               height: float | None = None) -> Push:
    """A push of ``force`` [N] (+ forward, on the back) over [start, start + duration) [s] at ``height`` [m]
    above the hip (None: the simulator's ``push_height``); by default the paper's push: 25 ms at mid-step
    of the first step."""
    return Push(start, duration, float(force), height)


def run(steps: int, mode: str, pushes: tuple[Push, ...] = (), *, integration_rate: bool = False,
        observer: bool | None = None, keep_qp: bool = False, settings: RunSettings = DEFAULT_SETTINGS,
        keep_records: bool = True, on_impact=None, pool: runner.LoopPool | None = None) -> RunResult:
    """``runner.run`` for ``steps`` impacts in ``mode`` with ``settings`` (``observer`` True/False overrides
    the disturbance observer); the other arguments are ``runner.run``'s."""
    ctx = context(settings.activate().robot)
    if observer is not None:
        settings = RunSettings(tuple(sorted({**dict(settings.controller), "disturbance_observer": observer}.items())),
                               settings.simulator, settings.perturbation, settings.full_trials, settings.profile,
                               settings.robot)
    ccfg = settings.ctrl_config(mode)
    return runner.run(steps=steps, mode=mode, pushes=pushes, sim_config=settings.sim_config(), ctrl_config=ccfg,
                      family=ctx.family, desc=ctx.desc, integration_rate=integration_rate, keep_qp=keep_qp,
                      perturbation=settings.perturbation, keep_records=keep_records, on_impact=on_impact, pool=pool)


def push_step_index(push: Push, T: float) -> int:
    """Index of the (nominal) step during which ``push`` ends (0 = first step; ``T`` the nominal step
    duration [s]): floor((start + duration) / T)."""
    return int(math.floor((push.start + push.duration) / T))


def trial_steps(push: Push, steps_after: int = SURVIVAL_STEPS) -> int:
    """The impacts a pushed run walks: up to the end of the push's step, then ``steps_after`` more."""
    return push_step_index(push, context().family.T) + 1 + steps_after


def push_run(push: Push, mode: str = "both", *, steps_after: int = SURVIVAL_STEPS, keep_qp: bool = False,
             settings: RunSettings = DEFAULT_SETTINGS, keep_records: bool = True, on_impact=None,
             pool: runner.LoopPool | None = None) -> RunResult:
    """One push, then ``steps_after`` more steps (:func:`trial_steps`). ``keep_records`` False: the outcome
    only (``runner.run``), as a survival trial needs; ``on_impact``: ``runner.run``'s early stop; ``pool``:
    ``runner.run``'s reuse of the loop and of the walk up to the push."""
    settings.activate()
    return run(trial_steps(push, steps_after), mode, (push,), keep_qp=keep_qp, settings=settings,
               keep_records=keep_records, on_impact=on_impact, pool=pool)


@functools.lru_cache(maxsize=1)
def loop_pool() -> runner.LoopPool:
    """This process's :class:`runner.LoopPool` (the survival trials' plants, controllers and walks to the
    push onsets, reused: bit-identical outcomes, tested)."""
    return runner.LoopPool()
