"""Shared test helpers: tolerant comparison that prints both sides, central finite differences.
(The project's packages are installed in the venv by scripts/setup, editable: no path set-up here.)"""
from __future__ import annotations

from pathlib import Path
from typing import Callable

import numpy as np

ROOT = Path(__file__).resolve().parents[1]

CONFIG = ROOT / "robots" / "biped7" / "description.yaml"


def assert_close(a, b, tol: float, what: str, rel: bool = False) -> None:
    """Assert max |a - b| <= tol (or <= tol * max(1, |b|_inf) with rel=True); print both on failure."""
    a = np.asarray(a, dtype=float)
    b = np.asarray(b, dtype=float)
    assert a.shape == b.shape, f"{what}: shape {a.shape} != {b.shape}"
    err = float(np.max(np.abs(a - b))) if a.size else 0.0
    bound = tol * max(1.0, float(np.max(np.abs(b)))) if rel and b.size else tol
    if not np.all(np.isfinite(a)) or not np.all(np.isfinite(b)) or err > bound:
        with np.printoptions(precision=12, suppress=False, linewidth=150):
            raise AssertionError(
                f"{what}: max |a - b| = {err:.3e} > {bound:.3e}\n  a = {a}\n  b = {b}\n  a - b = {a - b}"
            )


def central_diff(f: Callable[[np.ndarray], np.ndarray], x: np.ndarray, h: float = 1e-6) -> np.ndarray:
    """Jacobian of f at x by central differences: column j = (f(x + h e_j) - f(x - h e_j)) / 2h.

    Returns shape f(x).shape + (len(x),); a scalar f gives the gradient (len(x),)."""
    x = np.asarray(x, dtype=float)
    f0 = np.asarray(f(x), dtype=float)
    out = np.empty(f0.shape + (x.size,))
    for j in range(x.size):
        e = np.zeros_like(x)
        e[j] = h
        out[..., j] = (np.asarray(f(x + e), dtype=float) - np.asarray(f(x - e), dtype=float)) / (2 * h)
    return out


def directional_diff(f: Callable[[float], np.ndarray], h: float = 1e-5) -> np.ndarray:
    """d/dt f(t) at t = 0 by a 4th-order central difference."""
    return (8 * (np.asarray(f(h)) - np.asarray(f(-h))) - (np.asarray(f(2 * h)) - np.asarray(f(-2 * h)))) / (12 * h)


def random_posture(rng: np.random.Generator, scale: float = 0.6) -> np.ndarray:
    """A moderate random q1..q6 [rad] (knees within their flexion range is not required for dynamics)."""
    return rng.uniform(-scale, scale, 6)


def rk4_step(f: Callable[[np.ndarray], np.ndarray], y: np.ndarray, dt: float) -> np.ndarray:
    k1 = f(y)
    k2 = f(y + 0.5 * dt * k1)
    k3 = f(y + 0.5 * dt * k2)
    k4 = f(y + dt * k3)
    return y + dt / 6.0 * (k1 + 2 * k2 + 2 * k3 + k4)


# --------------------------------------------------------------------------------------------------
# Independent hand-written reference for the fixed-stance-foot chain (no Pinocchio): planar kinematics
# of the seven bodies from the paper's relative angles q1..q6. u(t) = (-sin t, cos t) is "up" rotated
# counter-clockwise by t; a leg segment hanging from the hip points along -u.
def _u(t: float) -> np.ndarray:
    return np.array([-np.sin(t), np.cos(t)])


def _du(t: float) -> np.ndarray:
    return np.array([-np.cos(t), -np.sin(t)])


def _bodies(desc):
    """(mass, inertia, terms, angle index) per body; a point = sum coef * u(theta[idx] + offset),
    theta = cumsum(q), idx -1 meaning the fixed stance foot (angle 0)."""
    ft, sh, th, to = desc.foot, desc.shin, desc.thigh, desc.torso
    half = -0.5 * np.pi  # u(t - pi/2) = (cos t, sin t): along the foot
    knee1 = [(sh.length, 0, 0.0)]
    hip = knee1 + [(th.length, 1, 0.0)]
    knee2 = hip + [(-th.length, 3, 0.0)]
    ankle2 = knee2 + [(-sh.length, 4, 0.0)]
    return [
        (ft.mass, ft.inertia, [(ft.com_forward, -1, half)], -1),
        (sh.mass, sh.inertia, [(sh.length - sh.com, 0, 0.0)], 0),
        (th.mass, th.inertia, knee1 + [(th.length - th.com, 1, 0.0)], 1),
        (to.mass, to.inertia, hip + [(to.com, 2, 0.0)], 2),
        (th.mass, th.inertia, hip + [(-th.com, 3, 0.0)], 3),
        (sh.mass, sh.inertia, knee2 + [(-sh.com, 4, 0.0)], 4),
        (ft.mass, ft.inertia, ankle2 + [(ft.com_forward, 5, half)], 5),
    ], ankle2


def _point(terms, theta, thetad=None):
    p = np.zeros(2)
    v = np.zeros(2)
    for coef, idx, off in terms:
        t = 0.0 if idx < 0 else theta[idx]
        p += coef * _u(t + off)
        if thetad is not None and idx >= 0:
            v += coef * _du(t + off) * thetad[idx]
    return p, v


def hand_kinetic_energy(desc, q, qd) -> float:
    theta, thetad = np.cumsum(q), np.cumsum(qd)
    ke = 0.0
    bodies, _ = _bodies(desc)
    for m, inertia, terms, idx in bodies:
        _, v = _point(terms, theta, thetad)
        w = 0.0 if idx < 0 else thetad[idx]
        ke += 0.5 * m * float(v @ v) + 0.5 * inertia * w * w
    return ke


def hand_potential_energy(desc, q) -> float:
    theta = np.cumsum(q)
    bodies, _ = _bodies(desc)
    return sum(m * desc.gravity * _point(terms, theta)[0][1] for m, _, terms, _ in bodies)


def hand_com(desc, q) -> np.ndarray:
    theta = np.cumsum(q)
    bodies, _ = _bodies(desc)
    tot = sum(b[0] for b in bodies)
    return sum(m * _point(terms, theta)[0] for m, _, terms, _ in bodies) / tot


def hand_swing_foot(desc, q) -> np.ndarray:
    """(x, z, absolute angle) of the swing ankle relative to the stance ankle."""
    _, ankle2 = _bodies(desc)
    p, _ = _point(ankle2, np.cumsum(q))
    return np.array([p[0], p[1], float(np.sum(q))])


def hand_mass_matrix(desc, q) -> np.ndarray:
    """A(q) from the hand kinetic energy by polarisation (exact up to rounding: KE is quadratic in q')."""
    n = len(q)
    E = np.eye(n)
    k = [hand_kinetic_energy(desc, q, E[i]) for i in range(n)]
    A = np.empty((n, n))
    for i in range(n):
        A[i, i] = 2 * k[i]
        for j in range(i + 1, n):
            A[i, j] = A[j, i] = hand_kinetic_energy(desc, q, E[i] + E[j]) - k[i] - k[j]
    return A


def assert_same_fields(a, b, what: str, tol: float = 0.0, relative: bool = False) -> None:
    """Every field of two dataclass instances equal: arrays and floats to ``tol`` (0 = bit-identical,
    NaN equals NaN; ``relative``: |x - y| <= tol max(1, |x|), for fields in N next to fields in rad),
    everything else with ==. The message names the field and both values."""
    import dataclasses
    import math
    for f in dataclasses.fields(a):
        x, y = getattr(a, f.name), getattr(b, f.name)
        if isinstance(x, np.ndarray) or isinstance(y, np.ndarray):
            x, y = np.asarray(x, float), np.asarray(y, float)
            bound = tol * np.maximum(1.0, np.abs(x)) if relative else tol
            ok = x.shape == y.shape and (np.array_equal(x, y, equal_nan=True) if tol == 0.0 else
                                         bool(np.all((np.abs(x - y) <= bound) | (np.isnan(x) & np.isnan(y)))))
        elif isinstance(x, float) and isinstance(y, float):
            bound = tol * max(1.0, abs(x)) if relative else tol
            ok = (x == y or (math.isnan(x) and math.isnan(y))) if tol == 0.0 else \
                (abs(x - y) <= bound or (math.isnan(x) and math.isnan(y)))
        else:
            ok = x == y
        assert ok, f"{what}: field {f.name} differs:\n  {x!r}\n  {y!r}"


def assert_same_run(a, b, tol: float = 0.0, skip_status: tuple[str, ...] = (), relative: bool = False) -> None:
    """Two runner.RunResult record for record: states, statuses and impacts (same counts first)."""
    import dataclasses
    assert len(a.records) == len(b.records), f"{len(a.records)} records vs {len(b.records)}"
    assert len(a.statuses) == len(b.statuses), f"{len(a.statuses)} statuses vs {len(b.statuses)}"
    assert len(a.impacts) == len(b.impacts), f"{len(a.impacts)} impacts vs {len(b.impacts)}"
    assert len(a.records) > 0
    for ra, rb in zip(a.records, b.records):
        assert_same_fields(ra, rb, f"record step {ra.step} t={ra.t}", tol, relative)
    for sa, sb in zip(a.statuses, b.statuses):
        if skip_status:
            sa = dataclasses.replace(sa, **{k: getattr(sb, k) for k in skip_status})
        assert_same_fields(sa, sb, f"status step {sa.step}", tol, relative)
    for ia, ib in zip(a.impacts, b.impacts):
        assert_same_fields(ia, ib, f"impact {ia.index}", tol, relative)
    assert (a.fallen, a.fall_cause, a.steps_walked) == (b.fallen, b.fall_cause, b.steps_walked)


def count_compiled_periods(patch) -> list:
    """Wrap the controller's compiled period (``controller_compiled.CompiledPeriod.compute``) through ``patch`` (a pytest
    ``monkeypatch`` or one of its contexts) so that every call appends whether the compiled period served
    it (True) or handed it back to the Python steps (False); returns that list."""
    from biped_controller.core.control import controller as C
    used: list = []
    orig = C.CompiledPeriod.compute

    def counting(self, *a):
        out = orig(self, *a)
        used.append(out is not None)
        return out
    patch.setattr(C.CompiledPeriod, "compute", counting)
    return used


def graph_params_with_push(tmp: Path, push: dict) -> Path:
    """config/graph.yaml with one push scheduled by the disturbance node (``push``: force [N], start [s],
    duration [s]) and the simulator waiting for it, written into ``tmp``; returns its path."""
    import yaml
    cfg = yaml.safe_load((ROOT / 'config' / 'graph.yaml').read_text())
    dist = cfg['disturbance']['ros__parameters']
    dist.update(schedule_forces=[push['force']], schedule_starts=[push['start']],
                schedule_durations=[push['duration']])
    cfg['simulator']['ros__parameters']['wait_for_pushes'] = 1
    out = tmp / 'graph.yaml'
    out.write_text(yaml.safe_dump(cfg))
    return out


def run_launch(cmd: list[str], env: dict, timeout: float = 300.0) -> str:
    """Run the launcher ``cmd`` (from the repository's root) to its end and return its combined output; kill it
    if it outlives ``timeout`` [s] (then the caller's return-code assertion fails with the output)."""
    import subprocess
    proc = subprocess.Popen(cmd, env=env, cwd=ROOT, stdout=subprocess.PIPE, stderr=subprocess.STDOUT, text=True)
    try:
        out, _ = proc.communicate(timeout=timeout)
    finally:
        if proc.poll() is None:
            proc.kill()
            proc.wait(10)
    assert proc.returncode == 0, out[-4000:]
    return out
