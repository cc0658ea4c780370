"""The second plant: the biped on MuJoCo (pip ``mujoco``), behind the same :class:`~biped_sim.plant.protocol.Plant`
interface as the rigid :class:`~biped_sim.plant.rigid.Simulator`.

MuJoCo + NumPy, the per-step bookkeeping compiled (``mujoco_kernels``, numba, bit-identical to the Python it
replaced); Pinocchio's ``FloatingModel`` only at reset and at impacts; no ROS.

Model: ``biped_model.mjcf.make_mjcf`` from the (perturbed) description and the ``mujoco_*`` settings of
``config/simulator.yaml``; ``qpos``/``qvel`` are the floating state ``x = [x_hip, z_hip, theta, lh, lk, la, rh,
rk, ra]``, ``v = dx/dt`` (the tests check M(x), the centre of mass and the bias forces against Pinocchio).

Time: MuJoCo steps of ``mujoco_timestep`` (8 per 1 ms control period), split exactly at every push start
and end (the step length is changed for that step), so a push delivers exactly force x duration; the joint
torques are held over the period (MuJoCo ``motor`` actuators, ``ctrlrange`` = the torque limits, and the
same clipping as the rigid plant). After ``mj_step`` from t0 to t1 the contact list and the constraint
forces are those MuJoCo computed at t0 and applied over [t0, t1] (semi-implicit Euler), so the ground's
impulse over the step is exactly h x force.

What differs from the rigid plant, by design:

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

import ctypes
import math
from dataclasses import dataclass, field
from pathlib import Path
from typing import Callable

import mujoco
import numpy as np

from biped_sim.plant.config import SimConfig, load_sim_config
from biped_sim.plant.perturbation import ZERO, PerturbationError, PlantPerturbation, SensorModel
from biped_sim.plant.period_grid import grid_end, period_knots
from biped_sim.plant.push import ScheduledPushes
from biped_sim.plant.records import FallInfo, ImpactRecord, Observation, StepRecord
from biped_model import numba_cache
from biped_model.description import LEFT, RobotDescription, load_description
from biped_model.floating import PAPER_FROM_URDF, FloatingModel, urdf_from_paper
from biped_model.layout import SnapshotUnsupported
from biped_model.mjcf import BODY_GEOMS, FLOOR_GEOM, MjcfContact, foot_geom_names, make_mjcf

TorqueFn = Callable[[float, np.ndarray, np.ndarray, int], np.ndarray]
FOOT_BODIES = ("left_foot", "right_foot")
# rows of the per-step contact summary (per foot): force x, force z, moment about that foot's ankle, normal
FX, FZ, MY, FN = range(4)
MUJOCO_KERNELS = "biped_sim.plant.mujoco_kernels"


def mujoco_library() -> Path:
    """MuJoCo's shared library as the Python bindings ship it (``libmujoco.so.<version>`` beside
    ``mujoco/__init__.py``): the library the bindings call, and the one ``mujoco_kernels.substeps`` calls."""
    here = Path(mujoco.__file__).parent
    libs = sorted(here.glob("libmujoco.so*"))
    if not libs:
        raise MujocoPlantError(f"MuJoCo's shared library libmujoco.so* not found in {here} (the mujoco wheel "
                               "ships it there; the compiled MuJoCo steps call it)")
    return libs[-1]


def load_kernels():
    """The compiled MuJoCo steps and their bookkeeping (``mujoco_kernels``), through ``numba_cache.load``
    (compiled on first use, then cached in ``build/numba-cache``), after loading :func:`mujoco_library`
    into the process's symbol space for numba (``llvmlite.binding.load_library_permanently``: the same
    library the bindings have loaded, found by its path), where ``substeps`` finds ``mj_step`` and
    ``mj_rnePostConstraint`` by name."""
    import llvmlite.binding as llvm

    llvm.load_library_permanently(str(mujoco_library()))
    return numba_cache.load(MUJOCO_KERNELS)


def opt_timestep_view(model: mujoco.MjModel) -> np.ndarray:
    """A one-element float64 view of ``model.opt.timestep`` in the ``mjModel`` struct itself (for the compiled
    steps, which set the step length per MuJoCo step as ``model.opt.timestep = h`` does). The bindings give the
    struct's address (``MjModel._address``), not the field's: the field is the one double among the struct's
    first 2 kB that follows two distinct values written through ``model.opt.timestep`` (then restored); the view
    is checked by writing through it and reading ``model.opt.timestep`` back. Valid while ``model`` lives."""
    n = 256
    words = (ctypes.c_double * n).from_address(model._address)
    old = model.opt.timestep
    found = None
    try:
        for probe in (1.2345678901234567e-3, 9.876543210987654e-4):
            model.opt.timestep = probe
            hits = {i for i in range(n) if words[i] == probe}
            found = hits if found is None else found & hits
        if found is None or len(found) != 1:
            raise MujocoPlantError(f"opt.timestep not found in the mjModel struct (candidates {sorted(found or ())}): "
                                   "the compiled MuJoCo steps cannot set the step length")
        view = np.ctypeslib.as_array((ctypes.c_double * 1).from_address(model._address + 8 * found.pop()))
        view[0] = 0.5
        if model.opt.timestep != 0.5:
            raise MujocoPlantError("the view of opt.timestep does not write model.opt.timestep")
    finally:
        model.opt.timestep = old
    return view


class MujocoPlantError(RuntimeError):
    """MuJoCo refused the generated model or reported a warning that invalidates the run."""


def contact_settings(cfg: SimConfig) -> MjcfContact:
    """The MJCF's engine and contact settings from ``config/simulator.yaml`` (``mujoco_*``)."""
    return MjcfContact(timestep=cfg.mujoco_timestep, integrator=cfg.mujoco_integrator, cone=cfg.mujoco_cone,
                       tolerance=cfg.mujoco_solver_tolerance,
                       solref=(cfg.mujoco_solref_timeconst, cfg.mujoco_solref_dampratio),
                       solimp=(cfg.mujoco_solimp_dmin, cfg.mujoco_solimp_dmax, cfg.mujoco_solimp_width),
                       foot_thickness=cfg.mujoco_foot_thickness, foot_width=cfg.mujoco_foot_width,
                       body_radius=cfg.mujoco_body_radius, shin_gap=cfg.mujoco_shin_capsule_gap,
                       sole_points=cfg.mujoco_sole_points)


# MuJoCo's integration state: time, qpos, qvel, act, qacc_warmstart, ctrl, the applied forces, equality flags,
# mocap, user data and plugin state -- all that mj_step reads from one call to the next
MJ_STATE = mujoco.mjtState.mjSTATE_INTEGRATION


@dataclass(frozen=True, eq=False)
class MujocoSnapshot:
    """Everything :class:`MujocoPlant` carries from one period to the next: MuJoCo's integration state
    (``mj_getState`` with ``MJ_STATE``), the plant's own floating state, stance, anchor, time and period
    index, the compiled bookkeeping's arrays (accumulators, sensing state, diagnostics; stance indices;
    constants with the stance anchor), the impacts so far (immutable, shared), the touchdown forces, the
    fall (None while walking) and the push schedule."""

    mj_state: np.ndarray
    x: np.ndarray
    v: np.ndarray
    stance: int
    anchor: np.ndarray
    t: float
    step_index: int
    impact_count: int
    impact_log: tuple[ImpactRecord, ...]
    touchdown_forces: tuple[float, ...]
    acc: np.ndarray
    ip: np.ndarray
    fp: np.ndarray
    fall: FallInfo | None
    pushes: tuple
    next_push_id: int


@dataclass(frozen=True, eq=False)
class CompiledPlant:
    """What a compiled closed loop outside the plant (``biped_controller.closed_loop.mujoco_loop_kernels``)
    needs to run this plant's MuJoCo steps and their bookkeeping (``mujoco_kernels``) in its own calls, as
    :meth:`MujocoPlant.step` runs them: every array is the plant's own (a view or the array itself, kept for
    the plant's life), so the loop's writes are the plant's state.

    ``kernels``: the plant's kernel module (its record row layout ``ROW_SIZE``, ``R_*``); ``model_address``,
    ``data_address``: MuJoCo's ``mjModel*`` and ``mjData*``; ``timestep``: the view of ``opt.timestep`` [s];
    ``mj_arrays``: MuJoCo's ``cfrc_ext``, ``xpos``, ``subtree_com``, ``qpos``, ``qvel``, ``xfrc_applied``,
    ``ctrl`` (views); ``acc``, ``ip``, ``fp``: the bookkeeping's accumulators, indices and constants;
    ``warnings``: the view of MuJoCo's warning counters, ``bad_warnings`` the indices that make a numerical
    fall; ``torque_min``, ``torque_max`` (6,) [N m] the torque limits in paper order; ``torso_com`` [m] the
    torso's centre of mass above the hip (where a push's height is measured from); ``mujoco_step`` [s]
    MuJoCo's step (``mujoco_timestep``)."""

    kernels: object
    model_address: int
    data_address: int
    timestep: np.ndarray
    mj_arrays: tuple
    acc: np.ndarray
    ip: np.ndarray
    fp: np.ndarray
    warnings: np.ndarray
    bad_warnings: np.ndarray
    torque_min: np.ndarray
    torque_max: np.ndarray
    torso_com: float
    mujoco_step: float

    def step_arguments(self) -> tuple:
        """The arguments of the compiled MuJoCo steps in the kernels' order: model, data, timestep, the seven
        MuJoCo arrays, acc, ip, fp, warnings, bad_warnings, torque_min, torque_max."""
        return (self.model_address, self.data_address, self.timestep, *self.mj_arrays, self.acc, self.ip, self.fp,
                self.warnings, self.bad_warnings, self.torque_min, self.torque_max)


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
        for k, side in enumerate(("left", "right")):
            for n in foot_geom_names(side, self.cfg.mujoco_sole_points):
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
        self._warn_number = self.data.warning.number    # a view: MuJoCo's warning counters
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
        # set to a function f(plant) to see the plant after every MuJoCo step's bookkeeping (the tests)
        self.probe: Callable[["MujocoPlant"], None] | None = None
        # the compiled bookkeeping of a MuJoCo step and its arrays (mujoco_kernels: acc the accumulators, the
        # sensing state and the diagnostics; ip the indices; fp the constants)
        k = self._k = load_kernels()
        self._after_step, self._begin, self._end, self._measure = k.after_step, k.begin_period, k.end_period, k.measure
        self._acc = np.zeros(k.ACC_SIZE)
        self._ip = np.zeros(k.IP_SIZE, dtype=np.int64)
        self._ip[k.I_FOOT_BODY:k.I_FOOT_BODY + 2] = self._foot_body
        self._ip[k.I_TORSO] = self._torso
        self._ip[k.I_LEG_BODY:k.I_LEG_BODY + 4] = self._leg_bodies
        self._ip[k.I_LEG_GEOM:k.I_LEG_GEOM + 4] = self._leg_capsules
        self._ip[k.I_TORSO_GEOM] = self._torso_capsule
        self._fp = np.zeros(k.FP_SIZE)
        dg = self._new_diagnostics()
        self._edge_band, self._roll_tilt = dg.edge_band, dg.roll_tilt
        ft = self.desc.foot
        self._fp[[k.F_THR, k.F_DEBOUNCE, k.F_HIP_MIN, k.F_TILT_MAX, k.F_EDGE_LO, k.F_EDGE_HI, k.F_CONE, k.F_ROLL]] = (
            self.cfg.mujoco_touch_threshold, self.cfg.mujoco_swing_debounce - 1e-12, self.cfg.mujoco_fall_hip_height,
            self.cfg.mujoco_fall_foot_tilt, ft.l_min + dg.edge_band, ft.l_max - dg.edge_band, 0.99 * self.desc.mu,
            dg.roll_tilt)
        self._touchdown_forces: list[float] = []
        self._mj_arrays = (self._cfrc, self._xpos, self._scom, self.data.qpos, self.data.qvel, self.data.xfrc_applied,
                           self.data.ctrl)
        # the period's MuJoCo steps in one compiled call (mujoco_kernels.substeps) with held torques and no probe
        # or trace; False: the Python loop, one iteration per MuJoCo step (the reference, bit-identical)
        self.compiled_steps = True
        self._substeps = k.substeps
        self._m_addr, self._d_addr = m._address, self.data._address
        self._timestep = opt_timestep_view(m)
        self._torso_com = float(self.desc.torso.com)
        self._sub_out = np.zeros(k.OUT_SIZE)
        self._compiled_plant: CompiledPlant | None = None
        self._new_stance(LEFT, 0.0)

    def _new_diagnostics(self) -> ContactDiagnostics:
        # the edge band: 1 mm, the rigid plant's tip boundary seen through a soft contact's corner spread; the
        # roll tilt: the sole's far end 0.1 mm above the floor (0.1 m x 1e-3 rad), far above the 0.36 um sink
        return ContactDiagnostics(edge_band=1e-3, roll_tilt=1e-3)

    @property
    def diagnostics(self) -> ContactDiagnostics:
        """The run's contact diagnostics so far (a snapshot; the kernel's counters, ``mujoco_kernels.A_DIAG``)."""
        a = self._acc[self._k.A_DIAG:self._k.A_DIAG + 9].tolist()
        return ContactDiagnostics(edge_band=self._edge_band, roll_tilt=self._roll_tilt, steps=int(a[0]), time=a[1],
                                  unloaded_time=a[2], edge_time=a[3], cone_time=a[4], tilt_time=a[5], max_cop=a[6],
                                  max_tilt=a[7], max_slip=a[8], touchdown_forces=list(self._touchdown_forces))

    def _new_stance(self, stance: int, anchor_x: float) -> None:
        """The kernel's view of a new stance foot: its index, its leg's first joint in x, its pitch now (the
        next MuJoCo step's start), its ankle's anchor; the swing foot's sensing starts afresh."""
        k, acc = self._k, self._acc
        self._ip[k.I_STANCE] = stance
        self._ip[k.I_J0] = 3 if stance == LEFT else 6
        acc[k.A_PITCH] = self.foot_pitch(self.x, stance)
        acc[k.A_UNLOADED_SINCE] = math.nan
        acc[k.A_ARMED] = 0.0
        self._fp[k.F_ANCHOR_X] = anchor_x

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
        self._acc[:] = 0.0
        self._touchdown_forces = []
        self._new_stance(stance, self.anchor[0])
        if self.trace is not None:
            self.trace = [(0.0, self.x.copy())]

    def snapshot(self) -> MujocoSnapshot:
        """The state between two periods (:class:`MujocoSnapshot`); :meth:`restore` brings it back, after
        which every period is bit-identical to the one that followed the snapshot (tested). Raises
        :class:`SnapshotUnsupported` with a sensor model (its noise generator and delay line are not part of
        the state) or while a step trace is kept."""
        if not self.sensor.identity:
            raise SnapshotUnsupported("MujocoPlant.snapshot: a sensor model (noise, quantisation, delay) carries "
                                      "state outside the plant's arrays")
        if self.trace is not None:
            raise SnapshotUnsupported("MujocoPlant.snapshot: a step trace is being kept")
        st = np.empty(mujoco.mj_stateSize(self.model, MJ_STATE))
        mujoco.mj_getState(self.model, self.data, st, MJ_STATE)
        return MujocoSnapshot(st, self.x.copy(), self.v.copy(), self.stance, self.anchor.copy(), self.t,
                              self.step_index, self.impact_count, tuple(self.impact_log),
                              tuple(self._touchdown_forces), self._acc.copy(), self._ip.copy(), self._fp.copy(),
                              None if self.fall is None else FallInfo(**self.fall.__dict__),
                              tuple(self.book.pushes), self.book.next_id)

    def restore(self, snap: MujocoSnapshot) -> None:
        """Back to the state of :meth:`snapshot`: MuJoCo's data reset (its warning counters and derived
        quantities cleared, as :meth:`reset` leaves them) and its integration state set (``mj_setState``); the
        plant's arrays copied in (the same objects go on: the compiled bookkeeping holds views of them)."""
        mujoco.mj_resetData(self.model, self.data)
        mujoco.mj_setState(self.model, self.data, snap.mj_state, MJ_STATE)
        self.x, self.v = snap.x.copy(), snap.v.copy()
        self.stance = snap.stance
        self.anchor = snap.anchor.copy()
        self.t = snap.t
        self.step_index = snap.step_index
        self.impact_count = snap.impact_count
        self.impact_log = list(snap.impact_log)
        self._touchdown_forces = list(snap.touchdown_forces)
        self._acc[:] = snap.acc
        self._ip[:] = snap.ip
        self._fp[:] = snap.fp
        self.fall = None if snap.fall is None else FallInfo(**snap.fall.__dict__)
        self.book = self._new_book()
        self.book.pushes.extend(snap.pushes)
        self.book.next_id = snap.next_push_id

    # ------------------------------------------------------------ queries
    @staticmethod
    def foot_pitch(x: np.ndarray, foot: int) -> float:
        """Absolute pitch of a foot [rad, counter-clockwise]: torso pitch + the leg's three joints."""
        return float(x[2] + (x[3] + x[4] + x[5] if foot == LEFT else x[6] + x[7] + x[8]))

    def measured(self, x: np.ndarray, v: np.ndarray, stance: int) -> tuple[np.ndarray, np.ndarray]:
        """Paper (q, q') as the robot measures them: encoders, with q1 (q1') the stance shin's angle (rate)
        to the ground = ankle encoder + the stance foot's pitch (rate) (``mujoco_kernels.measure``: the
        operations of ``paper_from_urdf`` and ``foot_pitch``, bit for bit)."""
        out = np.empty(12)
        if type(x) is not np.ndarray or type(v) is not np.ndarray:
            x, v = np.ascontiguousarray(x, dtype=float), np.ascontiguousarray(v, dtype=float)
        self._measure(x, v, PAPER_FROM_URDF[stance], 3 if stance == LEFT else 6, out)
        return out[:6], out[6:]

    def observe(self) -> Observation:
        q, qd = self.measured(self.x, self.v, self.stance)
        pitch = float(self.x[2])          # the IMU: the torso's pitch in the world, = q1 + q2 + q3 here
        rate = float(self.v[2])           # and its gyro's pitch rate
        if self.sensor.identity:
            obs = object.__new__(Observation)     # the fields at once (as StepRecord's)
            obs.__dict__.update(step=self.step_index, t=self.t, stance=self.stance, q=q, qd=qd, pitch=pitch,
                                pitch_rate=rate)
            return obs
        self.sensor.sample(self.step_index, self.stance, q, qd, pitch, rate)
        stance, qs, qds = self.sensor.reading(self.step_index)
        return Observation(self.step_index, self.t, stance, qs, qds, *self.sensor.imu_reading(self.step_index))

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
        end ``t`` of a period: the ``numerical`` fall (the state's sum from the last step's bookkeeping:
        finite iff every entry is)."""
        if not math.isfinite(self._acc[self._k.A_STATE_SUM]):
            return FallInfo("numerical", t, "non-finite state")
        warn = self._warn_number
        b0, b1, b2 = self._bad_warnings
        if warn[b0] or warn[b1] or warn[b2]:
            for w in self._bad_warnings:
                if warn[w] > 0:
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

    def _substeps_python(self, knots: list, t_start: float, t_grid_end: float, fn: TorqueFn | None,
                         obs_stance: int) -> tuple[bool, FallInfo | None, float, float]:
        """The period's MuJoCo steps over ``knots``, one Python iteration each (the reference of
        :meth:`_substeps_compiled`; the only path for a torque function ``fn``, a ``probe`` or a ``trace``).
        Returns (touchdown, fall or None, the period's end [s], the pushes' impulse over it [N s])."""
        m, d, k = self.model, self.data, self._k
        lo, hi = self._lo, self._hi
        acc = self._acc
        has_pushes = bool(self.book.pushes)
        impulse = 0.0
        t_end = t_grid_end
        touchdown = False
        fall = None
        opt, mj_step, rne, after = self._opt, mujoco.mj_step, mujoco.mj_rnePostConstraint, self._after_step
        arrays = self._mj_arrays
        ip, fp = self._ip, self._fp
        pushes = ()
        for t0, t1 in zip(knots[:-1], knots[1:]):
            if has_pushes:
                pushes = self.interval_pushes(t0, t1)
                self._set_push(pushes)
            if fn is not None:
                d.ctrl[:] = urdf_from_paper(np.clip(fn(t0 - t_start, *self.measured(d.qpos, d.qvel, obs_stance),
                                                       obs_stance), lo, hi), obs_stance)
            opt.timestep = t1 - t0
            mj_step(m, d)
            rne(m, d)                    # cfrc_ext: the forces of t0, applied over [t0, t1]
            code = after(*arrays, acc, ip, fp, t0, t1)
            if pushes:
                # the push's work: its force times its point's x rate (hip x rate - height cos(th) th'), with the
                # velocity the positions advance with (semi-implicit Euler)
                h = t1 - t0
                xv, thv, th = d.qvel[0], d.qvel[2], d.qpos[2]
                for f, hgt in pushes:
                    impulse += f * h
                    acc[k.A_WORK] += h * f * (xv - hgt * math.cos(th) * thv)
            if self.probe is not None:
                self.probe(self)
            if self.trace is not None:
                self.trace.append((t1, d.qpos.copy()))
            if code:
                if code == k.TOUCHDOWN:
                    touchdown = True
                    t_end = t1
                    break
                fall = self._check_fall(t1, d.qpos.tolist(), int(acc[k.A_HIT]))
                if fall is not None:
                    t_end = t1
                    break
        return touchdown, fall, t_end, impulse

    def compiled_plant(self) -> CompiledPlant:
        """The plant's arrays and constants a compiled loop outside it runs its MuJoCo steps with
        (:class:`CompiledPlant`; one object for the plant's life)."""
        if self._compiled_plant is None:
            self._compiled_plant = CompiledPlant(
                self._k, self._m_addr, self._d_addr, self._timestep, self._mj_arrays, self._acc, self._ip, self._fp,
                self._warn_number, np.array(self._bad_warnings, dtype=np.int64), self._lo, self._hi,
                self._torso_com, self._h)
        return self._compiled_plant

    def _substeps_compiled(self, knots: list, t_grid_end: float, i0: int = 0, impulse0: float = 0.0
                           ) -> tuple[bool, FallInfo | None, float, float]:
        """:meth:`_substeps_python` for held torques in compiled calls (``mujoco_kernels.substeps``): one call
        runs the MuJoCo steps until the period's end, a touchdown or a possible fall (named here by
        :meth:`_check_fall`; the steps go on after one that is not a fall). Same returns, bit for bit.
        ``i0``, ``impulse0``: resume after ``i0`` intervals with the pushes' impulse so far."""
        k, acc = self._k, self._acc
        kn = np.array(knots, dtype=float)
        pushes = self.push_rows()
        out = self._sub_out
        out[k.O_DONE] = 0.0
        out[k.O_IMPULSE] = impulse0
        n = len(knots) - 1
        i = i0
        while i < n:
            code = self._substeps(self._m_addr, self._d_addr, self._timestep, kn, i, pushes, self._torso_com,
                                  *self._mj_arrays, acc, self._ip, self._fp, out)
            i = int(out[k.O_DONE])
            if code == k.CONTINUE:
                break
            t1 = knots[i]
            if code == k.TOUCHDOWN:
                return True, None, t1, float(out[k.O_IMPULSE])
            fall = self._check_fall(t1, self.data.qpos.tolist(), int(acc[k.A_HIT]))
            if fall is not None:
                return False, fall, t1, float(out[k.O_IMPULSE])
        return False, None, t_grid_end, float(out[k.O_IMPULSE])

    def step(self, torque: np.ndarray | TorqueFn) -> StepRecord:
        """Advance one control period (see the module docstring): held paper-order torques [N m] for the
        stance the controller was told (or a function ``(s, q, qd, stance)`` of the measured state, evaluated
        at every MuJoCo step). Ends at the next grid instant, at a sensed touchdown or at a fall.

        After each ``mj_step`` (+ ``mj_rnePostConstraint`` for the bodies' external forces) one compiled call
        (``mujoco_kernels.after_step``) does the step's bookkeeping -- contact rows, the period's sums, work,
        diagnostics, touchdown sensing, the fall pre-check -- on MuJoCo's arrays in place; Python names a fall,
        adds a push's work and builds the record."""
        if self.fall is not None:
            raise RuntimeError("the robot has fallen; reset() the plant")
        d, k = self.data, self._k
        dt_nom = self.cfg.control_period
        t_start = self.t
        t_grid_end = grid_end(t_start, dt_nom)
        obs_stance = self.stance
        if not self.sensor.identity:
            if callable(torque):
                raise PerturbationError("noise_q/noise_qd/delay", "a torque function sees the true state at every "
                                        "step: use held torques (the sensor model applies to observe())")
            obs_stance = self.observe().stance
        lo, hi = self._lo, self._hi
        stance0 = self.stance
        if callable(torque):
            fn = torque
            torque = fn(0.0, *self.measured(self.x, self.v, obs_stance), obs_stance)
        else:
            fn = None
        n_sub = max(1, int(math.ceil((t_grid_end - t_start) / self._h - 1e-9)))
        has_pushes = bool(self.book.pushes)
        knots = period_knots(t_start, t_grid_end, n_sub,
                             (c for p in self.book.pushes for c in (p.start, p.end)) if has_pushes else ())
        first = self.interval_pushes(knots[0], knots[1]) if has_pushes else ()
        impacts0 = self.impact_count
        acc = self._acc
        # the period's record row: the clipped torque (to ctrl in URDF order), the state at its start; sums zeroed
        row = np.empty(k.ROW_SIZE)
        self._begin(np.ascontiguousarray(torque, dtype=float), lo, hi, PAPER_FROM_URDF[obs_stance],
                    PAPER_FROM_URDF[stance0], obs_stance != stance0, d.qpos, d.qvel, d.ctrl, acc, row)
        if fn is None and self.probe is None and self.trace is None and self.compiled_steps:
            touchdown, fall, t_end, impulse = self._substeps_compiled(knots, t_grid_end)
        else:
            touchdown, fall, t_end, impulse = self._substeps_python(knots, t_start, t_grid_end, fn, obs_stance)
        push_force = float(sum(f for f, _ in first)) if first else 0.0
        return self._finish_period(row, t_start, t_end, stance0, touchdown, fall, impulse, push_force, impacts0)

    def _finish_period(self, row: np.ndarray, t_start: float, t_end: float, stance0: int, touchdown: bool,
                       fall: FallInfo | None, impulse: float, push_force: float, impacts0: int) -> StepRecord:
        """The period [t_start, t_end] after its MuJoCo steps: the state copied out, the touchdown's impact
        record and the exchange of the legs, the numerical check, the mean wrench (``end_period``), the clock,
        and the period's :class:`StepRecord` (its arrays views of ``row``)."""
        d, k, acc = self.data, self._k, self._acc
        self.x, self.v = d.qpos.copy(), d.qvel.copy()
        x0, v0 = row[k.R_X:k.R_X + 9], row[k.R_V:k.R_V + 9]
        if touchdown:
            sw = 3 * (1 - stance0)
            self._touchdown_forces.append(float(acc[k.A_ROWS + 4 * (1 - stance0) + 3]))
            self._touchdown(t_start, t_end, x0, v0, acc[k.A_OWN + sw:k.A_OWN + sw + 3].copy(), float(acc[k.A_WORK]))
        if fall is None:
            fall = self._check_numerics(t_end)
        self.fall = fall
        self._end(acc, row, stance0, touchdown, t_end - t_start)
        self.step_index += 1
        self.t = t_end
        # the record's fields at once (a frozen dataclass's __init__ costs as much as the rest of the period),
        # its arrays views of the period's row
        rec = object.__new__(StepRecord)
        rec.__dict__.update(step=self.step_index - 1, t=t_start, stance=stance0, q=row[k.R_Q:k.R_Q + 6],
                            qd=row[k.R_QD:k.R_QD + 6], base=row[k.R_BASE:k.R_BASE + 3],
                            base_dot=row[k.R_BASE_DOT:k.R_BASE_DOT + 3], x=x0, v=v0,
                            torque=row[k.R_TORQUE:k.R_TORQUE + 6], wrench=row[k.R_WRENCH:k.R_WRENCH + 3],
                            cop=float(row[k.R_COP]), push_force=push_force, impacts=impacts0,
                            fallen=fall is not None, fall_cause=fall.cause if fall else "",
                            fall_detail=fall.detail if fall else "", t_end=t_end, push_impulse=impulse)
        return rec

    def finish_compiled_period(self, code: int, done: int, knots: list, t_start: float, t_grid_end: float,
                               impulse: float, row: np.ndarray, push_force: float) -> StepRecord:
        """A period the compiled closed loop (``mujoco_loop_kernels``) ran and handed back after its MuJoCo
        steps stopped with ``code`` (``mujoco_kernels.substeps``) after ``done`` intervals of ``knots``
        (CONTINUE: every interval, the end state to check for numerics): the fall named, the steps resumed
        after a possible fall that is none, then :meth:`_finish_period`, as :meth:`step` does. ``row`` the
        period's row (its own array: the record's arrays are views of it); the plant's clock at the period's
        start."""
        k = self._k
        touchdown, fall, t_end = False, None, t_grid_end
        if code == k.TOUCHDOWN:
            touchdown, t_end = True, knots[done]
        elif code == k.MAYBE_FALL:
            fall = self._check_fall(knots[done], self.data.qpos.tolist(), int(self._acc[k.A_HIT]))
            if fall is not None:
                t_end = knots[done]
            else:
                touchdown, fall, t_end, impulse = self._substeps_compiled(knots, t_grid_end, done, impulse)
        return self._finish_period(row, t_start, t_end, self.stance, touchdown, fall, impulse, push_force,
                                   self.impact_count)

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
        self._new_stance(new, self.anchor[0])
