"""The second plant: the biped on MuJoCo (pip ``mujoco``), behind the same :class:`~biped_sim.plant.protocol.Plant`
interface as the rigid :class:`~biped_sim.plant.rigid.Simulator`.

Pure Python (MuJoCo + NumPy; Pinocchio's ``FloatingModel`` only at reset and at impacts), no ROS.

Model: ``biped_sim.robot.mjcf.make_mjcf`` from the (perturbed) description and the ``mujoco_*`` settings of
``config/simulator.yaml``; ``qpos``/``qvel`` are the floating state ``x = [x_hip, z_hip, theta, lh, lk, la, rh,
rk, ra]``, ``v = dx/dt`` (the tests check M(x), the centre of mass and the bias forces against Pinocchio).

Time: MuJoCo steps of ``mujoco_timestep`` (2 per 1 ms control period), split exactly at every push start
and end (the step length is changed for that step), so a push delivers exactly force x duration; the joint
torques are held over the period (MuJoCo ``motor`` actuators, ``ctrlrange`` = the torque limits, and the
same clipping as the rigid plant). After ``mj_step`` from t0 to t1 the contact list and the constraint
forces are those MuJoCo computed at t0 and applied over [t0, t1] (semi-implicit Euler), so the ground's
impulse over the step is exactly h x force.

What differs from the rigid plant, by design (issue 24):

* **Sensed, not declared.** A foot is *loaded* when the normal force of its contacts exceeds
  ``mujoco_touch_threshold``. The swing foot is *armed* once it has stayed unloaded for
  ``mujoco_swing_debounce``; the first MuJoCo step whose force loads an armed swing foot is the touchdown,
  sensed at that step's end (a foot switch reads the force the step applied). The control period ends
  there (as the rigid plant's ends at the impact), the legs exchange roles and the controller relabels on
  the next observation. No re-pose, no impact map: the impact is MuJoCo's, spread over its steps.
* **Physical falls** (``FallInfo.cause``): ``body_contact`` (a capsule of torso, thigh or shin touches the
  floor), ``hip_low`` (hip height below ``mujoco_fall_hip_height``), ``foot_rotated`` (the stance foot's
  pitch beyond ``mujoco_fall_foot_tilt``), ``numerical`` (a non-finite state or a MuJoCo warning). A
  centre of pressure at the sole's edge, a friction cone reached or a foot unloading for a moment are
  *not* falls: they are counted in :class:`ContactDiagnostics` (``diagnostics``).
* **The stance ankle measured against the ground.** :meth:`observe` reports q1 = the stance ankle encoder
  + the stance foot's pitch (the shin's angle to the floor, as a body IMU and the encoders give it) and
  q1' likewise; q2..q6 are the encoders. A foot that rocks on its soft contact would otherwise put the
  rocking into q1' (``../shared/notes/mujoco-first-look.md``). The records keep the true encoders.

Records (``plant.records``), the instants they describe on this plant (DESIGN.md):

* :class:`StepRecord` of period [t, t_end): ``q, qd, x, v`` the true state at t (encoders: ``q`` is the
  paper order of the URDF joints); ``wrench`` = [F_x, F_z, m] the **mean over the period** of the ground's
  total action on the robot (both feet: in single support the stance foot's; the rear foot's while it is
  still on the floor after a touchdown), moment m counter-clockwise about the stance ankle, *except* the
  landing foot's action over a period that ends in a touchdown, which the impact carries; ``cop`` = m / F_z;
  ``push_force`` the push at t, ``push_impulse`` its exact integral over the period. Linear momentum
  therefore closes per period: P(t_end) - P(t) = (F_x, F_z - M g) (t_end - t) + (push_impulse, 0) + the
  impact's impulse when the period ends in a touchdown (up to the O(h^2) of the discrete centre-of-mass
  velocity).
* :class:`ImpactRecord` of a touchdown sensed at t: the window is the period it ends, [t_minus, t];
  ``x_minus, v_minus`` the state at t_minus (the period's start), ``x_flat = x_plus``, ``v_plus =
  v_plus_projected`` the state at t (nothing is re-posed or projected), ``foot_tilt`` the landing foot's
  pitch at t, ``impulse`` the ground's impulse on the landing foot over the window (x, z, moment about its
  ankle), ``energy_loss`` the mechanical energy dissipated over the window, E(t_minus) - E(t) + the
  actuators' and the push's work (E = kinetic + potential; the work summed per step with the velocity the
  positions advance with), ``old_foot_velocity`` the released foot's (x, z, pitch) rates at t.
"""
from __future__ import annotations

import math
from dataclasses import dataclass, field
from typing import Callable

import mujoco
import numpy as np

from biped_sim.plant.config import SimConfig, load_sim_config
from biped_sim.plant.perturbation import ZERO, PerturbationError, PlantPerturbation, SensorModel
from biped_sim.plant.push import ScheduledPushes
from biped_sim.plant.records import FallInfo, ImpactRecord, Observation, StepRecord
from biped_sim.robot.description import LEFT, RobotDescription, load_description
from biped_sim.robot.floating import FloatingModel, paper_from_urdf, urdf_from_paper
from biped_sim.robot.mjcf import BODY_GEOMS, FLOOR_GEOM, FOOT_GEOMS, MjcfContact, make_mjcf

TorqueFn = Callable[[float, np.ndarray, np.ndarray, int], np.ndarray]
FOOT_BODIES = ("left_foot", "right_foot")
# rows of the per-step contact summary (per foot): force x, force z, moment about that foot's ankle, normal
FX, FZ, MY, FN = range(4)


class MujocoPlantError(RuntimeError):
    """MuJoCo refused the generated model or reported a warning that invalidates the run."""


def contact_settings(cfg: SimConfig) -> MjcfContact:
    """The MJCF's engine and contact settings from ``config/simulator.yaml`` (``mujoco_*``)."""
    return MjcfContact(timestep=cfg.mujoco_timestep, integrator=cfg.mujoco_integrator, cone=cfg.mujoco_cone,
                       tolerance=cfg.mujoco_solver_tolerance,
                       solref=(cfg.mujoco_solref_timeconst, cfg.mujoco_solref_dampratio),
                       solimp=(cfg.mujoco_solimp_dmin, cfg.mujoco_solimp_dmax, cfg.mujoco_solimp_width),
                       foot_thickness=cfg.mujoco_foot_thickness, foot_width=cfg.mujoco_foot_width,
                       body_radius=cfg.mujoco_body_radius, shin_gap=cfg.mujoco_shin_capsule_gap)


@dataclass
class ContactDiagnostics:
    """Contact-limit excursions of a run (the rigid plant would have declared some of them falls).

    Per MuJoCo step (time in simulated seconds), for the stance foot's own contact: ``unloaded_time`` its
    normal force below the touch threshold; ``edge_time`` its centre of pressure within ``edge_band`` of the
    heel or the toe (the rigid plant's tip_heel / tip_toe boundary); ``cone_time`` |F_x| >= 0.99 mu F_z
    (sliding on the friction cone: the rigid plant's slip); ``max_cop`` the largest |l| [m] ahead of or
    behind the ankle (loaded steps only); ``max_tilt`` the largest |pitch| of the stance foot [rad] and
    ``tilt_time`` the time it exceeded ``roll_tilt``; ``max_slip`` the largest horizontal displacement of the
    stance ankle from where its touchdown put it [m]; ``steps`` MuJoCo steps counted."""

    edge_band: float
    roll_tilt: float
    steps: int = 0
    time: float = 0.0
    unloaded_time: float = 0.0
    edge_time: float = 0.0
    cone_time: float = 0.0
    tilt_time: float = 0.0
    max_cop: float = 0.0
    max_tilt: float = 0.0
    max_slip: float = 0.0
    touchdown_forces: list = field(default_factory=list)   # landing foot's normal force when sensed [N]

    def as_dict(self) -> dict:
        return {k: (float(v) if isinstance(v, (float, np.floating)) else v) for k, v in self.__dict__.items()
                if k != "touchdown_forces"}


class MujocoPlant(ScheduledPushes):
    """The biped on MuJoCo (see the module docstring). ``perturbation`` as for the rigid plant: the model
    is built from ``perturbation.apply(desc)`` (masses, centres of mass, inertias, friction), the sensors
    (noise, delay) act on :meth:`observe` only."""

    name = "mujoco"

    def __init__(self, desc: RobotDescription | None = None, config: SimConfig | None = None,
                 perturbation: PlantPerturbation | None = None):
        self.nominal_desc = desc if desc is not None else load_description()
        self.perturbation = perturbation if perturbation is not None else ZERO
        self.desc = self.perturbation.apply(self.nominal_desc)
        self.sensor = SensorModel(self.perturbation)
        self.cfg = (config if config is not None else load_sim_config()).validate()
        self.fm = FloatingModel(self.desc)          # Pinocchio: reset (paper -> floating) and impacts only
        self.mjcf = make_mjcf(self.desc, contact_settings(self.cfg))
        try:
            self.model = mujoco.MjModel.from_xml_string(self.mjcf)
        except ValueError as exc:
            raise MujocoPlantError(f"MuJoCo rejected the generated model: {exc}") from exc
        self.data = mujoco.MjData(self.model)
        m = self.model
        gid = lambda n: mujoco.mj_name2id(m, mujoco.mjtObj.mjOBJ_GEOM, n)   # noqa: E731
        # geom id -> 0 left foot, 1 right foot, 2 a body capsule, 3 the floor
        self._kind = np.full(m.ngeom, 3, dtype=np.int64)
        for k, n in enumerate(FOOT_GEOMS):
            self._kind[gid(n)] = k
        for n in BODY_GEOMS:
            self._kind[gid(n)] = 2
        self._floor = gid(FLOOR_GEOM)
        self._geom_names = [mujoco.mj_id2name(m, mujoco.mjtObj.mjOBJ_GEOM, i) for i in range(m.ngeom)]
        self._foot_body = tuple(mujoco.mj_name2id(m, mujoco.mjtObj.mjOBJ_BODY, n) for n in FOOT_BODIES)
        self._torso = mujoco.mj_name2id(m, mujoco.mjtObj.mjOBJ_BODY, "torso")
        legs = ("left_thigh", "left_shin", "right_thigh", "right_shin")
        self._leg_bodies = np.array([mujoco.mj_name2id(m, mujoco.mjtObj.mjOBJ_BODY, n) for n in legs])
        self._leg_capsules = [gid(n + "_capsule") for n in legs]
        self._leg_bodies_l = self._leg_bodies.tolist()
        self._xp: list = []
        # MuJoCo's arrays as numpy views, taken once (the same memory for the plant's life; mj_resetData keeps it)
        self._opt = m.opt
        self._cfrc, self._xpos, self._scom = self.data.cfrc_ext, self.data.xpos, self.data.subtree_com
        self._xfrc_torso = self.data.xfrc_applied[self._torso]
        self._torso_capsule = gid("torso_capsule")
        self._elliptic = self.cfg.mujoco_cone == "elliptic"
        self._bad_warnings = tuple(int(w) for w in (mujoco.mjtWarning.mjWARN_BADQACC, mujoco.mjtWarning.mjWARN_BADQPOS,
                                                    mujoco.mjtWarning.mjWARN_BADQVEL))
        self._h = self.cfg.mujoco_timestep
        self._lo, self._hi = (np.array(b) for b in self.desc.torque_limits())
        self._ar3 = np.arange(3)
        self.x = np.zeros(9)
        self.v = np.zeros(9)
        self.stance = LEFT
        self.anchor = np.zeros(3)
        self.t = 0.0
        self.step_index = 0
        self.fall: FallInfo | None = None
        self.impact_count = 0
        self.impact_log: list[ImpactRecord] = []
        self.book = self._new_book()
        self.trace: list[tuple[float, np.ndarray]] | None = None   # set to [] to log (t, x) at every MuJoCo step
        self.diagnostics = self._new_diagnostics()
        self._unloaded_since: float | None = None
        self._armed = False

    def _new_diagnostics(self) -> ContactDiagnostics:
        # the edge band: 1 mm, the rigid plant's tip boundary seen through a soft contact's corner spread; the
        # roll tilt: the sole's far end 0.1 mm above the floor (0.1 m x 1e-3 rad), far above the 0.36 um sink
        return ContactDiagnostics(edge_band=1e-3, roll_tilt=1e-3)

    # ------------------------------------------------------------ setup
    def reset(self, q: np.ndarray, qd: np.ndarray, stance: int = LEFT, ankle_x: float = 0.0) -> None:
        """Start from paper (q, q') with the stance foot flat at (ankle_x, 0) (the swing foot where q puts it)."""
        self.x, self.v = self.fm.state_from_paper(np.asarray(q, float), np.asarray(qd, float), stance, ankle_x)
        mujoco.mj_resetData(self.model, self.data)
        self.data.qpos[:] = self.x
        self.data.qvel[:] = self.v
        mujoco.mj_forward(self.model, self.data)
        self.stance = stance
        self.anchor = np.array([ankle_x, 0.0, 0.0])
        self.t = 0.0
        self.step_index = 0
        self.fall = None
        self.impact_count = 0
        self.impact_log = []
        self.book = self._new_book()
        self.sensor.reset()
        self.diagnostics = self._new_diagnostics()
        self._unloaded_since = None
        self._armed = False
        if self.trace is not None:
            self.trace = [(0.0, self.x.copy())]

    # ------------------------------------------------------------ queries
    @staticmethod
    def foot_pitch(x: np.ndarray, foot: int) -> float:
        """Absolute pitch of a foot [rad, counter-clockwise]: torso pitch + the leg's three joints."""
        return float(x[2] + (x[3] + x[4] + x[5] if foot == LEFT else x[6] + x[7] + x[8]))

    def measured(self, x: np.ndarray, v: np.ndarray, stance: int) -> tuple[np.ndarray, np.ndarray]:
        """Paper (q, q') as the robot measures them: encoders, with q1 (q1') the stance shin's angle (rate)
        to the ground = ankle encoder + the stance foot's pitch (rate)."""
        q, qd = paper_from_urdf(x[3:], stance), paper_from_urdf(v[3:], stance)
        q[0] += self.foot_pitch(x, stance)
        qd[0] += self.foot_pitch(v, stance)
        return q, qd

    def observe(self) -> Observation:
        q, qd = self.measured(self.x, self.v, self.stance)
        pitch = float(self.x[2])          # the IMU (issue 22): the torso's pitch in the world, = q1 + q2 + q3 here
        if self.sensor.identity:
            return Observation(self.step_index, self.t, self.stance, q, qd, pitch)
        self.sensor.sample(self.step_index, self.stance, q, qd, pitch)
        stance, qs, qds = self.sensor.reading(self.step_index)
        return Observation(self.step_index, self.t, stance, qs, qds, self.sensor.pitch_reading(self.step_index))

    # ------------------------------------------------------------ contacts
    def _contacts(self) -> tuple[np.ndarray, int]:
        """Per foot [F_x, F_z, m about its ankle (ccw), normal force] of the ground on it, of the last step's
        start (the forces applied over that step); and a body capsule touching the floor (its geom id, or -1).

        From MuJoCo's per-body external forces (``mj_rnePostConstraint`` -> ``cfrc_ext``: force f and moment
        tau_c about the robot's subtree centre of mass c, world frame): the moment about the ankle p is
        tau_p = tau_c + (c - p) x f, counter-clockwise = -tau_p,y; on a flat floor the normal force is f_z.
        A thigh or shin with any external force, or a torso whose external force differs from the push
        (``xfrc_applied``), touches the floor. :meth:`contacts_from_list` computes the same from the
        contact list (the tests compare them)."""
        mujoco.mj_rnePostConstraint(self.model, self.data)
        cf = self._cfrc.tolist()
        xp = self._xpos.tolist()
        cx, _, cz = self._scom[self._torso].tolist()
        rows = []
        for b in self._foot_body:
            _, ty, _, fx, _, fz = cf[b]
            px, _, pz = xp[b]
            rows.append([fx, fz, -(ty + (cz - pz) * fx - (cx - px) * fz), fz])
        hit = -1
        for b, g in zip(self._leg_bodies_l, self._leg_capsules):
            f = cf[b]
            if f[3] != 0.0 or f[4] != 0.0 or f[5] != 0.0:
                hit = g
                break
        else:
            push = self._xfrc_torso[:3].tolist()
            f = cf[self._torso][3:]
            if max(abs(f[i] - push[i]) for i in range(3)) > 1e-9 * (1.0 + abs(push[0])):
                hit = self._torso_capsule
        self._xp = xp
        return rows, hit

    def contacts_from_list(self) -> tuple[np.ndarray, int]:
        """:meth:`_contacts` computed from MuJoCo's contact list and constraint forces instead (slower; the
        tests' cross-check): per contact the force of geom1 on geom2 in the contact frame, rows normal and
        two tangents (elliptic cone: ``efc_force``; pyramidal: ``mj_contactForce``), turned to the world."""
        d = self.data
        out = np.zeros((2, 4))
        n = d.ncon
        if n == 0:
            return out, -1
        con = d.contact
        g = con.geom
        adr = con.efc_address
        robot_is_2 = g[:, 0] == self._floor
        rg = np.where(robot_is_2, g[:, 1], g[:, 0])
        kind = self._kind[rg]
        ok = adr >= 0
        hit = -1
        body = (kind == 2) & ok
        if body.any():
            hit = int(rg[np.argmax(body)])
        if self._elliptic:
            f3 = d.efc_force[adr[:, None] + self._ar3]
        else:
            f3 = np.zeros((n, 3))
            buf = np.zeros(6)
            for i in range(n):
                if adr[i] >= 0:
                    mujoco.mj_contactForce(self.model, d, i, buf)
                    f3[i] = buf[:3]
        f3[~ok] = 0.0
        # force of geom1 on geom2 in the contact frame (rows: normal, tangent 1, tangent 2) -> world, on the robot
        F = np.einsum("ni,nij->nj", f3, con.frame.reshape(n, 3, 3))
        F[~robot_is_2] *= -1.0
        for k in (0, 1):
            s = kind == k
            if not s.any():
                continue
            r = con.pos[s] - d.xpos[self._foot_body[k]]
            Fs = F[s]
            out[k, FX] = Fs[:, 0].sum()
            out[k, FZ] = Fs[:, 2].sum()
            out[k, MY] = float(np.sum(r[:, 0] * Fs[:, 2] - r[:, 2] * Fs[:, 0]))
            out[k, FN] = f3[s, 0].sum()
        return out, hit

    # ------------------------------------------------------------ stepping
    def _set_push(self, pushes) -> None:
        """The pushes as a force on the torso at its centre of mass plus the moment of the force's offset along
        the torso axis ((height - com) (-sin th, 0, cos th) x (F, 0, 0) = (0, (height - com) cos th F, 0))."""
        xf = self.data.xfrc_applied[self._torso]
        xf[:] = 0.0
        th = self.data.qpos[2]
        for f, h in pushes:
            xf[0] += f
            xf[4] += (h - self.desc.torso.com) * math.cos(th) * f
        return None

    def _energy(self, x: np.ndarray, v: np.ndarray) -> float:
        import pinocchio as pin
        M = self.fm.mass_matrix(x)
        com = pin.centerOfMass(self.fm.model, self.fm.data, x)
        return float(0.5 * v @ M @ v + self.fm.mass * self.desc.gravity * com[2])

    def _check_numerics(self, t: float) -> FallInfo | None:
        """A non-finite state or a MuJoCo warning (bad qacc, qpos, qvel: MuJoCo then resets the state) by the
        end ``t`` of a period: the ``numerical`` fall."""
        if not math.isfinite(float(self.x.sum() + self.v.sum())):
            return FallInfo("numerical", t, "non-finite state")
        warn = self.data.warning
        for w in self._bad_warnings:
            if warn[w].number > 0:
                return FallInfo("numerical", t, f"MuJoCo warning {mujoco.mjtWarning(w).name}")
        return None

    def _check_fall(self, t: float, x: list, hit: int) -> FallInfo | None:
        """The physical falls (module docstring) at ``t``, configuration ``x`` (a list), ``hit`` a body
        capsule's geom id touching the floor (or -1)."""
        if hit >= 0:
            return FallInfo("body_contact", t, f"{self._geom_names[hit]} touches the floor",
                            dict(geom=self._geom_names[hit]))
        if x[1] < self.cfg.mujoco_fall_hip_height:
            return FallInfo("hip_low", t, f"hip at {x[1]:.3f} m, below {self.cfg.mujoco_fall_hip_height} m",
                            dict(z_hip=float(x[1])))
        tilt = self.foot_pitch(x, self.stance)
        if abs(tilt) > self.cfg.mujoco_fall_foot_tilt:
            side = "toe" if tilt < 0 else "heel"
            return FallInfo("foot_rotated", t, f"stance foot pitched {tilt:+.3f} rad (on its {side}), beyond "
                            f"{self.cfg.mujoco_fall_foot_tilt} rad", dict(pitch=tilt))
        return None

    def _diagnose(self, c: list, h: float, x) -> None:
        """Count the contact-limit excursions of one MuJoCo step (``c`` per foot rows, ``x`` the step's start)."""
        dg = self.diagnostics
        fx, fz, my, fn = c[self.stance]
        dg.steps += 1
        dg.time += h
        if fn < self.cfg.mujoco_touch_threshold:
            dg.unloaded_time += h
        else:
            l = my / fz
            if abs(l) > dg.max_cop:
                dg.max_cop = abs(l)
            ft = self.desc.foot
            if l < ft.l_min + dg.edge_band or l > ft.l_max - dg.edge_band:
                dg.edge_time += h
            if abs(fx) >= 0.99 * self.desc.mu * fz:
                dg.cone_time += h
        tilt = abs(self.foot_pitch(x, self.stance))
        if tilt > dg.max_tilt:
            dg.max_tilt = tilt
        if tilt > dg.roll_tilt:
            dg.tilt_time += h
        slip = abs(self._xp[self._foot_body[self.stance]][0] - self.anchor[0])
        if slip > dg.max_slip:
            dg.max_slip = slip

    def step(self, torque: np.ndarray | TorqueFn) -> StepRecord:
        """Advance one control period (see the module docstring): held paper-order torques [N m] for the
        stance the controller was told (or a function ``(s, q, qd, stance)`` of the measured state, evaluated
        at every MuJoCo step). Ends at the next grid instant, at a sensed touchdown or at a fall."""
        if self.fall is not None:
            raise RuntimeError("the robot has fallen; reset() the plant")
        m, d = self.model, self.data
        dt_nom = self.cfg.control_period
        t_start = self.t
        t_grid_end = (math.floor(t_start / dt_nom + 1e-6) + 1) * dt_nom
        obs_stance = self.stance
        if not self.sensor.identity:
            if callable(torque):
                raise PerturbationError("noise_q/noise_qd/delay", "a torque function sees the true state at every "
                                        "step: use held torques (the sensor model applies to observe())")
            obs_stance = self.observe().stance
        if callable(torque):
            fn = torque
            applied = np.clip(fn(0.0, *self.measured(self.x, self.v, obs_stance), obs_stance), self._lo, self._hi)
        else:
            fn = None
            applied = np.clip(np.asarray(torque, dtype=float), self._lo, self._hi)
        tj = urdf_from_paper(applied, obs_stance)
        if obs_stance != self.stance:
            applied = paper_from_urdf(tj, self.stance)
        n_sub = max(1, int(math.ceil((t_grid_end - t_start) / self._h - 1e-9)))
        hh = (t_grid_end - t_start) / n_sub
        knots = [t_start + i * hh for i in range(n_sub)] + [t_grid_end]
        cuts = {c for p in self.pushes for c in (p.start, p.end) if t_start < c < t_grid_end}
        knots = sorted(set(knots) | cuts)
        x0, v0 = self.x.copy(), self.v.copy()
        q, qd = paper_from_urdf(x0[3:], self.stance), paper_from_urdf(v0[3:], self.stance)
        first = self.interval_pushes(knots[0], knots[1])
        stance0 = self.stance
        impacts0 = self.impact_count
        by_foot = [[0.0] * 3, [0.0] * 3]   # per foot: sum h [F_x, F_z, m about the stance ankle]
        own = [[0.0] * 3, [0.0] * 3]       # per foot: sum h [F_x, F_z, m about its own ankle]
        impulse = 0.0
        work = 0.0
        t_end = t_grid_end
        touchdown = False
        d.ctrl[:] = tj
        opt, mj_step = self._opt, mujoco.mj_step
        thr = self.cfg.mujoco_touch_threshold
        debounce = self.cfg.mujoco_swing_debounce - 1e-12
        swing = 1 - stance0
        foot_st, foot_sw = self._foot_body[stance0], self._foot_body[swing]
        has_pushes = bool(self.book.pushes)
        tq = tj.tolist()
        x_prev = x0.tolist()
        for t0, t1 in zip(knots[:-1], knots[1:]):
            h = t1 - t0
            pushes = self.interval_pushes(t0, t1) if has_pushes else ()
            if has_pushes:
                self._set_push(pushes)
            if fn is not None:
                d.ctrl[:] = urdf_from_paper(np.clip(fn(t0 - t_start, *self.measured(d.qpos, d.qvel, obs_stance),
                                                       obs_stance), self._lo, self._hi), obs_stance)
                tq = d.ctrl.tolist()
            opt.timestep = h
            mj_step(m, d)
            cl, hit = self._contacts()          # at t0, applied over [t0, t1]
            xl = d.qpos.tolist()
            vl = d.qvel.tolist()
            # work over the step with the velocity the positions advance with (semi-implicit Euler): actuators,
            # and each push times its point's x rate (hip x rate - height cos(th) th')
            work += h * sum(tq[i] * vl[3 + i] for i in range(6))
            for f, hgt in pushes:
                impulse += f * h
                work += h * f * (vl[0] - hgt * math.cos(xl[2]) * vl[2])
            xp = self._xp
            ax, _, az = xp[foot_st]
            for k, ck in enumerate(cl):
                if ck[FZ] == 0.0 and ck[FX] == 0.0:
                    continue
                o, bf = own[k], by_foot[k]
                o[0] += h * ck[FX]
                o[1] += h * ck[FZ]
                o[2] += h * ck[MY]
                kx, _, kz = xp[foot_sw if k == swing else foot_st]
                bf[0] += h * ck[FX]
                bf[1] += h * ck[FZ]
                bf[2] += h * (ck[MY] + (kx - ax) * ck[FZ] - (kz - az) * ck[FX])
            self._diagnose(cl, h, x_prev)
            if self.trace is not None:
                self.trace.append((t1, d.qpos.copy()))
            # touchdown sensing on the swing foot's normal force (the force of the step just taken)
            if cl[swing][FN] < thr:
                if self._unloaded_since is None:
                    self._unloaded_since = t0
                if t1 - self._unloaded_since >= debounce:
                    self._armed = True
            elif self._armed:
                touchdown = True
            else:
                self._unloaded_since = None
            x_prev = xl
            if touchdown:
                t_end = t1
                self.x, self.v = d.qpos.copy(), d.qvel.copy()
                self.diagnostics.touchdown_forces.append(float(cl[swing][FN]))
                self._touchdown(t_start, t1, x0, v0, np.array(own[swing]), work)
                break
            fall = self._check_fall(t1, xl, hit)
            if fall is not None:
                self.fall = fall
                t_end = t1
                break
        if not touchdown:
            self.x, self.v = d.qpos.copy(), d.qvel.copy()
        if self.fall is None:
            self.fall = self._check_numerics(t_end)
        dt = t_end - t_start
        total = np.array(by_foot[stance0]) + (0.0 if touchdown else np.array(by_foot[1 - stance0]))
        w = total / dt
        self.step_index += 1
        self.t = t_end
        return StepRecord(step=self.step_index - 1, t=t_start, stance=stance0, q=q, qd=qd, base=x0[:3].copy(),
                          base_dot=v0[:3].copy(), x=x0, v=v0, torque=applied, wrench=w,
                          cop=float(w[2] / w[1]) if w[1] != 0 else math.nan,
                          push_force=float(sum(f for f, _ in first)), impacts=impacts0,
                          fallen=self.fall is not None, fall_cause=self.fall.cause if self.fall else "",
                          fall_detail=self.fall.detail if self.fall else "", t_end=t_end, push_impulse=impulse)

    def _touchdown(self, t_minus: float, t: float, x_minus: np.ndarray, v_minus: np.ndarray,
                   impulse: np.ndarray, work: float) -> None:
        """The swing foot's sensed touchdown at ``t``: log the window [t_minus, t] as an :class:`ImpactRecord`
        (module docstring), exchange the legs' roles, anchor the new stance ankle where it is."""
        old = self.stance
        new = 1 - old
        x, v = self.x, self.v
        ank = self.fm.foot_pose(x, new)
        self.impact_count += 1
        self.impact_log.append(ImpactRecord(
            index=self.impact_count, t=t, old_stance=old, new_stance=new, x_minus=x_minus.copy(),
            v_minus=v_minus.copy(), foot_tilt=self.foot_pitch(x, new), x_flat=x.copy(), v_plus=v.copy(),
            x_plus=x.copy(), v_plus_projected=v.copy(), impulse=np.array(impulse, dtype=float),
            energy_loss=self._energy(x_minus, v_minus) - self._energy(x, v) + work,
            old_foot_velocity=self.fm.foot_velocity(x, v, old), ankle_x=float(ank[0])))
        self.stance = new
        self.anchor = np.array([float(ank[0]), 0.0, 0.0])
        self._unloaded_since = None
        self._armed = False
