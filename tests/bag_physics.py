"""An independent physics check of a recorded run: the bag (read with ``mcap`` + ``mcap_ros2`` only) and
``robots/biped7/description.yaml`` (read with ``yaml`` only), no project code. Used by test_graph (a walk with a push off
the control grid) and test_faults (a push cut short by a fall).

Own model: the planar chain of DESIGN.md (floating x = [x_hip, z_hip, theta, lh, lk, la, rh, rk, ra], every
angle counter-clockwise in the sagittal view, each joint child w.r.t. parent going down from the torso,
centres of mass on the link axes, the foot's at its ankle), so its linear momentum and kinetic energy are
sums over seven bodies. Its conventions are checked on the bag itself: the stance ankle it computes must be
on the ground and at rest in every recorded state.

Checks:
- ``push_report``: ``/sim/push`` gives every period [t, t + period) the impulse F x |[t, t + period) cut with
  [start, end)| of the ``/push_events`` push (zero outside the window), and the total;
- ``momentum_residuals``: per period, P(t_k+1) - P(t_k) - (R(t_k) dt + J_push + J_impact - M g dt e_z), with R
  the ``/ground_reaction`` force at the period start (left-rectangle rule: the residual is O(dR/dt dt^2),
  a few 1e-3 N s where R changes fastest, against 0.25 N s for 250 N over one period);
- ``impact_reports``: every ``/sim/impacts`` message: the momentum jump equals the ground impulse, the energy
  lost equals KE(v-) - KE(v+) at x_flat, the re-pose changes the landing ankle only, by -foot_tilt, the landing
  ankle is at rest after it, and the next ``/sim/state`` (stamped at the impact) starts from x_plus.
"""
from __future__ import annotations

import math
from pathlib import Path

import numpy as np
import yaml

ROOT = Path(__file__).resolve().parents[1]
URDF_JOINTS = ("left_hip", "left_knee", "left_ankle", "right_hip", "right_knee", "right_ankle")


def load_bag(bag: Path) -> dict[str, list]:
    """{topic: [decoded message, ...]} in log-time order."""
    from mcap.reader import make_reader
    from mcap_ros2.decoder import DecoderFactory
    bag = Path(bag)
    path = bag if bag.is_file() else sorted(bag.glob("*.mcap"))[0]
    out: dict[str, list] = {}
    with open(path, "rb") as fh:
        reader = make_reader(fh, decoder_factories=[DecoderFactory()])
        for _s, ch, _m, msg in reader.iter_decoded_messages(log_time_order=True):
            out.setdefault(ch.topic, []).append(msg)
    return out


def ns(stamp) -> int:
    return int(stamp.sec) * 1_000_000_000 + int(stamp.nanosec)


def _up(a: float) -> np.ndarray:
    """(0, 1) turned counter-clockwise by a in the sagittal view (x right, z up)."""
    return np.array([-math.sin(a), math.cos(a)])


def _dup(a: float) -> np.ndarray:
    return np.array([-math.cos(a), -math.sin(a)])


class PlanarBiped:
    """Masses, centres of mass and inertias from robots/biped7/description.yaml; momentum and kinetic energy."""

    def __init__(self, path: Path = ROOT / "robots" / "biped7" / "description.yaml"):
        d = yaml.safe_load(Path(path).read_text(encoding="utf-8"))

        def link(name):
            g = d[name]
            return tuple(float(g[k]["value"]) for k in ("length", "mass", "com_from_proximal", "inertia"))
        self.gravity = float(d["gravity"]["value"])
        self.torso, self.thigh, self.shin = link("torso"), link("thigh"), link("shin")
        f = d["foot"]
        self.foot = (float(f["mass"]["value"]), float(f["inertia"]["value"]))
        assert float(f["com_forward"]["value"]) == 0.0 and float(f["ankle_height"]["value"]) == 0.0, \
            "this model puts the foot's centre of mass at its ankle, on the sole line"
        self.mass = self.torso[1] + 2 * (self.thigh[1] + self.shin[1] + self.foot[0])

    def bodies(self, x, v):
        """[(mass, inertia, CoM velocity (2,), angular rate)], [(ankle position, ankle velocity)] per leg."""
        x, v = np.asarray(x, float), np.asarray(v, float)
        hip, hipd, th, thd = x[:2], v[:2], x[2], v[2]
        L, m, c, inertia = self.torso
        out = [(m, inertia, hipd + c * _dup(th) * thd, thd)]
        ankles = []
        for leg in (0, 1):
            j, jd = x[3 + 3 * leg:6 + 3 * leg], v[3 + 3 * leg:6 + 3 * leg]
            a1, w1 = th + j[0], thd + jd[0]
            a2, w2 = a1 + j[1], w1 + jd[1]
            w3 = w2 + jd[2]
            Lt, mt, ct, It = self.thigh
            Ls, ms, cs, Is = self.shin
            out.append((mt, It, hipd - ct * _dup(a1) * w1, w1))
            knee, kneed = hip - Lt * _up(a1), hipd - Lt * _dup(a1) * w1
            out.append((ms, Is, kneed - cs * _dup(a2) * w2, w2))
            ankle, ankled = knee - Ls * _up(a2), kneed - Ls * _dup(a2) * w2
            out.append((self.foot[0], self.foot[1], ankled, w3))
            ankles.append((ankle, ankled))
        return out, ankles

    def momentum(self, x, v) -> np.ndarray:
        return sum(m * vc for m, _, vc, _ in self.bodies(x, v)[0])

    def kinetic_energy(self, x, v) -> float:
        return float(sum(0.5 * m * vc @ vc + 0.5 * inertia * w * w for m, inertia, vc, w in self.bodies(x, v)[0]))


def floating_state(msg) -> tuple[np.ndarray, np.ndarray]:
    """(x, v) of a SimState: DESIGN.md's q_paper = [-la, -lk, -lh, rh, rk, ra] with the left foot in stance
    (mirrored for the right)."""
    def joints(p):
        p = np.asarray(p, float)
        stance, swing = -p[:3][::-1], p[3:]
        return np.concatenate([stance, swing] if msg.stance == 0 else [swing, stance])
    return (np.concatenate([np.asarray(msg.base, float), joints(msg.q)]),
            np.concatenate([np.asarray(msg.base_dot, float), joints(msg.q_dot)]))


def states(B) -> list:
    return sorted(B["/sim/state"], key=lambda m: m.sequence)


def push_report(B) -> dict:
    """Per-period impulse of /sim/push against the /push_events window (one push)."""
    (ev,) = B["/push_events"]
    start, end, force = ev.start, ev.start + ev.duration, ev.force
    worst, outside, total, touched = 0.0, [], 0.0, 0
    for m in sorted(B["/sim/push"], key=lambda m: ns(m.stamp)):
        t0 = ns(m.stamp) * 1e-9
        t1 = t0 + m.period
        if t1 <= start or t0 >= end:
            if m.impulse != 0.0:
                outside.append((t0, m.impulse))
        else:
            touched += 1
            worst = max(worst, abs(m.impulse - force * (min(t1, end) - max(t0, start))))
        total += m.impulse
    return dict(start=start, duration=ev.duration, end=end, force=force, total=total, periods_touched=touched,
                impulse_outside=outside, worst_period_error=worst)


def ankle_check(B, model: PlanarBiped) -> float:
    """Largest stance-ankle height or speed over the recorded states (0 when the model's conventions hold)."""
    worst = 0.0
    for s in states(B):
        ankle, ankled = model.bodies(*floating_state(s))[1][s.stance]
        worst = max(worst, abs(float(ankle[1])), float(np.max(np.abs(ankled))))
    return worst


def joint_states_check(B) -> float:
    """Largest difference between /joint_states and the URDF joints mapped from /sim/state (same stamps)."""
    js = {ns(m.header.stamp): m for m in B["/joint_states"]}
    worst, n = 0.0, 0
    for s in states(B):
        m = js.get(ns(s.stamp))
        if m is None or s.fallen:
            continue
        x, v = floating_state(s)
        pos, vel = dict(zip(m.name, m.position)), dict(zip(m.name, m.velocity))
        worst = max([worst] + [abs(pos[j] - x[3 + i]) for i, j in enumerate(URDF_JOINTS)]
                    + [abs(vel[j] - v[3 + i]) for i, j in enumerate(URDF_JOINTS)])
        n += 1
    assert n > 0
    return worst


def momentum_residuals(B, model: PlanarBiped) -> np.ndarray:
    """Rows (t_k, dt, residual x, residual z, ground impulse x over the period, impact at the end?)."""
    S = states(B)
    P = [model.momentum(*floating_state(s)) for s in S]
    wrench = {ns(m.header.stamp): m.wrench.force for m in B["/ground_reaction"]}
    push = {ns(m.stamp): m for m in B["/sim/push"]}
    impact = {ns(m.stamp): m for m in B.get("/sim/impacts", [])}
    Mg = model.mass * model.gravity
    rows = []
    for k in range(len(S) - 1):
        t0, t1 = ns(S[k].stamp), ns(S[k + 1].stamp)
        if S[k + 1].fallen or t0 not in push:
            continue
        dt = push[t0].period
        assert abs(t0 + dt * 1e9 - t1) <= 1.0, (t0, dt, t1)     # the period ends where the next state starts
        f = wrench[t0]
        J_imp = np.array(impact[t1].impulse[:2]) if t1 in impact else np.zeros(2)
        expected = np.array([f.x * dt + push[t0].impulse, (f.z - Mg) * dt]) + J_imp
        r = P[k + 1] - P[k] - expected
        rows.append((t0 * 1e-9, dt, r[0], r[1], f.x * dt + J_imp[0], float(t1 in impact)))
    return np.array(rows)


def impact_reports(B, model: PlanarBiped) -> list[dict]:
    by_stamp = {ns(s.stamp): s for s in states(B)}
    out = []
    for m in sorted(B.get("/sim/impacts", []), key=lambda m: m.index):
        x_minus, x_flat = np.array(m.x_minus), np.array(m.x_flat)
        v_minus, v_plus = np.array(m.v_minus), np.array(m.v_plus)
        ankle = 5 if m.new_stance == 0 else 8
        repose = x_flat - x_minus
        others = np.delete(repose, ankle)
        jump = model.momentum(x_flat, v_plus) - model.momentum(x_flat, v_minus)
        loss = model.kinetic_energy(x_flat, v_minus) - model.kinetic_energy(x_flat, v_plus)
        landing = model.bodies(x_flat, v_plus)[1][m.new_stance]
        placed = model.bodies(np.array(m.x_plus), np.array(m.v_plus_projected))[1][m.new_stance]
        nxt = by_stamp.get(ns(m.stamp))
        start_err = math.inf
        if nxt is not None:
            x, v = floating_state(nxt)
            start_err = float(max(np.max(np.abs(x - np.array(m.x_plus))),
                                  np.max(np.abs(v - np.array(m.v_plus_projected)))))
        out.append(dict(index=m.index, t=ns(m.stamp) * 1e-9, impulse=list(m.impulse),
                        momentum_error=float(np.max(np.abs(jump - np.array(m.impulse[:2])))),
                        energy_loss=m.energy_loss, energy_loss_model=loss,
                        repose_error=float(max(abs(repose[ankle] + m.foot_tilt), np.max(np.abs(others)))),
                        landing_ankle_speed=float(np.max(np.abs(landing[1]))),
                        landing_ankle_height_after=abs(float(placed[0][1])),
                        next_state_error=start_err))
    return out
