"""Plant perturbations: the simulated robot differs from the controller's model.

Pure Python (NumPy, PyYAML), no ROS. Perturbations live in the simulator only: the controller keeps
the nominal :class:`~biped_model.description.RobotDescription` (``robots/biped7/description.yaml``), while
``Simulator(desc, config, perturbation)`` integrates the *plant* ``perturbation.apply(desc)`` and hands
the controller what its sensors report (:class:`SensorModel`).

Three kinds, all in one frozen :class:`PlantPerturbation` (every field defaults to "no perturbation"):

* model error, per link kind (the two legs are perturbed alike: the description has one thigh, one
  shin and one foot):

  - ``<link>_mass_scale`` [-]: plant mass = scale x nominal mass (the inertia about the centre of mass
    is *not* rescaled with it; set ``<link>_inertia_scale`` too for a uniformly denser link);
  - ``<link>_com_shift`` [m]: the centre of mass moves along the link's axis, away from its proximal
    joint for a positive shift (torso: up from the hip; thigh: down from the hip; shin: down from the
    knee); for the foot, forward along the sole (``Foot.com_forward``, + towards the toe). The shifted
    centre of mass must stay on the link ([0, length]) or on the sole ([l_min, l_max]). A shift across
    the link (e.g. a torso centre of mass ahead of the hip line) cannot be expressed by the description
    (``Link.com`` is a distance along the axis) and is not offered;
  - ``<link>_inertia_scale`` [-]: rotational inertia about the centre of mass (normal to the sagittal
    plane) = scale x nominal;

* ground friction ``mu`` [-] of the plant (``None``: the description's); the simulator's slip check
  ``|F_x| <= mu F_z`` uses it, the controller's friction rows keep the nominal mu;
* sensing: Gaussian noise of standard deviation ``noise_q`` [rad] on each paper joint angle q1..q6 and
  ``noise_qd`` [rad/s] on each joint rate, encoder quantisation of the angles (``encoder_bits``, 0 = none),
  a torso pitch sensor (IMU) with Gaussian noise ``noise_pitch`` [rad] on its pitch and ``noise_pitch_rate``
  [rad/s] on its pitch rate (gyro), and a delay of ``delay`` control periods; ``seed`` seeds the noise (``numpy.random.default_rng(seed)``).

Sensor model (:class:`SensorModel`): at the start of every control period k the sensors take a sample
of the true (stance, q, q') and add noise, q_s = q + noise_q z_q, q'_s = q' + noise_qd z_qd, with
(z_q, z_qd) two fresh vectors of 6 standard normal draws (always drawn, in this order, whatever the
standard deviations, so one seed gives the same noise sequence at every noise level). With
``encoder_bits`` = b > 0 each angle is then quantised as an absolute encoder of b bits per turn reads it,
q_s <- Delta round(q_s / Delta), Delta = 2 pi / 2^b [rad] (14 bits: 3.835e-4 rad); the rates are the
rate sensor's (noise only). The IMU reports the torso's pitch in the world, theta = foot pitch + q1 + q2 +
q3 (counter-clockwise positive, as the paper's angles; the rigid plant's stance foot is flat, so
theta = q1 + q2 + q3 there), plus noise_pitch z_p, z_p drawn from a second generator
``default_rng([seed, 1])`` (so the joint noise sequence of a seed is the same with or without an IMU).
The IMU's gyro reports the torso's pitch rate theta' (the true q1' + q2' + q3' on a flat stance foot) plus
noise_pitch_rate z_r, z_r drawn from a third generator ``default_rng([seed, 2])`` (so neither sequence above
changes with it); the controller does not use the rate today (the estimator takes the pitch), the ROS graph
publishes it on ``/imu``. Pitch and rate are part of the delayed sample. The controller
at period k receives the sample of period k - delay (the first sample while k < delay: the sensors
report the initial state until the pipeline is full). The stance flag is part of the delayed sample (a
touchdown reaches the controller ``delay`` periods late); the time and the period index are not: the
controller's clock is the plant's. With ``touchdown_delayed`` False the touchdown is reported at once
instead (contact switches outside the delayed pipeline, an event-triggered fresh measurement): the first
sample of a new stance is delivered in the period it is taken and held until the delayed samples are all
of the new stance (period k receives the sample of max(k - delay, first period of the current stance)).
"Period" means a control period of the simulator, which an impact
cuts short (``Simulator.step``), so a delay of d periods is d x control_period except across an
impact. A zero perturbation (:attr:`PlantPerturbation.is_zero`) is the identity: the same description
object and the true observation, bit for bit.
"""
from __future__ import annotations

import dataclasses
import math
from dataclasses import dataclass, fields
from typing import Any, Mapping

import numpy as np

from biped_model.description import RobotDescription
from biped_model.finite import finite_number

#: the link kinds of the description that may be perturbed
LINKS: tuple[str, ...] = ("torso", "thigh", "shin", "foot")
#: largest delay accepted [control periods] (a second at 1 kHz: far beyond anything walkable)
MAX_DELAY = 1000
#: largest encoder resolution accepted [bits per turn] (beyond 52 bits a float64 angle has no finer step)
MAX_ENCODER_BITS = 52


class PerturbationError(ValueError):
    """A perturbation field is invalid; ``field`` names it (the message says why)."""

    def __init__(self, field: str, message: str) -> None:
        super().__init__(f"perturbation '{field}': {message}")
        self.field = field


@dataclass(frozen=True)
class PlantPerturbation:
    """How the simulated plant differs from the nominal description (see the module docstring).

    Defaults are the identity. Units: scales [-], shifts [m], noise [rad] and [rad/s], delay [control
    periods], seed a non-negative integer. Validated on construction (:class:`PerturbationError` naming
    the field); the shifts are checked against a description by :meth:`apply`."""

    torso_mass_scale: float = 1.0
    thigh_mass_scale: float = 1.0
    shin_mass_scale: float = 1.0
    foot_mass_scale: float = 1.0
    torso_com_shift: float = 0.0      # [m] along the torso, up from the hip
    thigh_com_shift: float = 0.0      # [m] along the thigh, down from the hip
    shin_com_shift: float = 0.0       # [m] along the shin, down from the knee
    foot_com_shift: float = 0.0       # [m] along the sole, forward of the ankle
    torso_inertia_scale: float = 1.0
    thigh_inertia_scale: float = 1.0
    shin_inertia_scale: float = 1.0
    foot_inertia_scale: float = 1.0
    mu: float | None = None           # plant's friction coefficient; None: the description's
    noise_q: float = 0.0              # [rad] std of the noise on each measured joint angle
    noise_qd: float = 0.0             # [rad/s] std of the noise on each measured joint rate
    encoder_bits: int = 0             # [bits per turn] quantisation of each measured angle; 0: none
    noise_pitch: float = 0.0          # [rad] std of the noise on the IMU's torso pitch
    noise_pitch_rate: float = 0.0     # [rad/s] std of the noise on the IMU's torso pitch rate (gyro)
    delay: int = 0                    # [control periods] between a sample and the controller
    touchdown_delayed: bool = True    # False: a touchdown restarts the delay line (reported at once)
    seed: int = 0                     # seed of the noise generator

    def __post_init__(self) -> None:
        for f in fields(self):
            v = getattr(self, f.name)
            if f.name == "touchdown_delayed":
                if not isinstance(v, (bool, np.bool_)):
                    raise PerturbationError(f.name, f"must be true or false, got {v!r}")
                object.__setattr__(self, f.name, bool(v))
                continue
            if f.name in ("delay", "seed", "encoder_bits"):
                if isinstance(v, bool) or not isinstance(v, (int, np.integer)):
                    raise PerturbationError(f.name, f"must be an integer, got {v!r}")
                hi = {"delay": MAX_DELAY, "seed": 2**63 - 1, "encoder_bits": MAX_ENCODER_BITS}[f.name]
                if not 0 <= int(v) <= hi:
                    raise PerturbationError(f.name, f"must be in [0, {hi}], got {v}")
                object.__setattr__(self, f.name, int(v))
                continue
            if f.name == "mu" and v is None:
                continue
            if isinstance(v, bool) or not isinstance(v, (int, float, np.floating, np.integer)):
                raise PerturbationError(f.name, f"must be a number, got {v!r}")
            v = finite_number(float(v), f.name, error=lambda m, name=f.name: PerturbationError(name, m),
                              message=f"must be finite, got {float(v)}")
            if f.name.endswith("_scale") and v <= 0.0:
                raise PerturbationError(f.name, f"a scale must be > 0, got {v}")
            if f.name == "mu" and v <= 0.0:
                raise PerturbationError(f.name, f"a friction coefficient must be > 0, got {v}")
            if f.name.startswith("noise_") and v < 0.0:
                raise PerturbationError(f.name, f"a standard deviation must be >= 0, got {v}")
            object.__setattr__(self, f.name, v)

    # ---------------------------------------------------------------- queries
    @property
    def model_is_nominal(self) -> bool:
        """No change of masses, centres of mass, inertias or friction."""
        return (all(getattr(self, f"{k}_mass_scale") == 1.0 and getattr(self, f"{k}_com_shift") == 0.0
                    and getattr(self, f"{k}_inertia_scale") == 1.0 for k in LINKS) and self.mu is None)

    @property
    def sensing_is_perfect(self) -> bool:
        """No noise and no delay: the controller sees the true state."""
        return (self.noise_q == 0.0 and self.noise_qd == 0.0 and self.delay == 0 and self.encoder_bits == 0
                and self.noise_pitch == 0.0 and self.noise_pitch_rate == 0.0)

    @property
    def encoder_step(self) -> float:
        """Quantisation step of the angles [rad]: 2 pi / 2^encoder_bits (0.0 without quantisation)."""
        return 2.0 * math.pi / 2.0 ** self.encoder_bits if self.encoder_bits else 0.0

    @property
    def is_zero(self) -> bool:
        """The identity perturbation (the seed alone changes nothing)."""
        return self.model_is_nominal and self.sensing_is_perfect

    def changed(self) -> dict[str, Any]:
        """The fields that differ from the identity (the seed only when there is noise)."""
        zero = PlantPerturbation()
        out = {f.name: getattr(self, f.name) for f in fields(self)
               if f.name != "seed" and getattr(self, f.name) != getattr(zero, f.name)
               and not (f.name == "touchdown_delayed" and self.delay == 0)}
        if self.noise_q or self.noise_qd or self.noise_pitch or self.noise_pitch_rate:
            out["seed"] = self.seed
        return out

    def label(self) -> str:
        """Short text of :meth:`changed` (``nominal`` for the identity), e.g. ``torso_mass_scale=1.1``."""
        ch = self.changed()
        return ", ".join(f"{k}={v:g}" if isinstance(v, float) else f"{k}={v}" for k, v in ch.items()) or "nominal"

    def as_dict(self) -> dict[str, Any]:
        """Every field (JSON/YAML-ready; ``mu`` None when nominal)."""
        return {f.name: getattr(self, f.name) for f in fields(self)}

    @classmethod
    def from_dict(cls, values: Mapping[str, Any]) -> "PlantPerturbation":
        """From a mapping of field names (unknown names raise :class:`PerturbationError` naming them)."""
        names = {f.name for f in fields(cls)}
        for k in values:
            if k not in names:
                raise PerturbationError(str(k), f"unknown field; known: {', '.join(sorted(names))}")
        return cls(**dict(values))

    # ---------------------------------------------------------------- the plant
    def apply(self, desc: RobotDescription) -> RobotDescription:
        """The plant's description: ``desc`` with masses and inertias scaled, centres of mass shifted and
        the friction replaced (``dataclasses.replace``; ``desc`` itself is not modified and is returned
        unchanged when :attr:`model_is_nominal`). Geometry, foot sole, torque and joint limits and gravity
        are the nominal ones. Raises :class:`PerturbationError` naming a shift that leaves its link."""
        if self.model_is_nominal:
            return desc
        new: dict[str, Any] = {}
        for k in ("torso", "thigh", "shin"):
            link = getattr(desc, k)
            com = link.com + getattr(self, f"{k}_com_shift")
            if not 0.0 <= com <= link.length:
                raise PerturbationError(f"{k}_com_shift", f"moves the {k}'s centre of mass to {com} m from its "
                                        f"proximal joint, off the link [0, {link.length}] m")
            new[k] = dataclasses.replace(link, mass=link.mass * getattr(self, f"{k}_mass_scale"), com=com,
                                         inertia=link.inertia * getattr(self, f"{k}_inertia_scale"))
        ft = desc.foot
        fc = ft.com_forward + self.foot_com_shift
        if not ft.l_min <= fc <= ft.l_max:
            raise PerturbationError("foot_com_shift", f"moves the foot's centre of mass to {fc} m ahead of the "
                                    f"ankle, off the sole [{ft.l_min}, {ft.l_max}] m")
        new["foot"] = dataclasses.replace(ft, mass=ft.mass * self.foot_mass_scale, com_forward=fc,
                                          inertia=ft.inertia * self.foot_inertia_scale)
        if self.mu is not None:
            new["mu"] = self.mu
        return dataclasses.replace(desc, **new)


ZERO = PlantPerturbation()


def plant_parameters(nominal: RobotDescription, perturbation: PlantPerturbation) -> dict[str, Any]:
    """What a reader of a recording needs to check the physics against the true plant (JSON/YAML-ready):
    the perturbation's fields, the plant's and the nominal physical values per link (mass [kg], centre of
    mass [m], inertia [kg m^2]), total masses, friction, and the sensor model. The plant is
    ``perturbation.apply(nominal)``."""
    plant = perturbation.apply(nominal)

    def links(d: RobotDescription) -> dict:
        out = {k: {"mass": getattr(d, k).mass, "com_from_proximal": getattr(d, k).com,
                   "inertia": getattr(d, k).inertia} for k in ("torso", "thigh", "shin")}
        out["foot"] = {"mass": d.foot.mass, "com_forward": d.foot.com_forward, "inertia": d.foot.inertia}
        return out
    return {
        "perturbation": perturbation.as_dict(),
        "changed": perturbation.changed(),
        "plant": {**links(plant), "mu": plant.mu, "total_mass": plant.total_mass, "gravity": plant.gravity},
        "nominal": {**links(nominal), "mu": nominal.mu, "total_mass": nominal.total_mass,
                    "source": nominal.source},
        "sensing": {"noise_q_std_rad": perturbation.noise_q, "noise_qd_std_rad_per_s": perturbation.noise_qd,
                    "encoder_bits": perturbation.encoder_bits, "encoder_step_rad": perturbation.encoder_step,
                    "noise_pitch_std_rad": perturbation.noise_pitch,
                    "noise_pitch_rate_std_rad_per_s": perturbation.noise_pitch_rate,
                    "delay_periods": perturbation.delay, "touchdown_delayed": perturbation.touchdown_delayed,
                    "seed": perturbation.seed,
                    "model": "Gaussian noise added to each paper joint angle and rate when sampled at a period "
                             "start, angles then quantised (encoder_bits), an IMU torso pitch and pitch rate with their own noise; "
                             "the controller receives the sample taken delay periods earlier "
                             "(stance included; time and period index are the current ones)"},
        "units": {"mass": "kg", "com": "m", "inertia": "kg m^2", "noise_q": "rad", "noise_qd": "rad/s",
                  "noise_pitch": "rad", "noise_pitch_rate": "rad/s", "delay": "control periods"},
    }


def plant_yaml(nominal: RobotDescription, perturbation: PlantPerturbation) -> str:
    """:func:`plant_parameters` as YAML (the ``/sim/plant`` message)."""
    import yaml
    return yaml.safe_dump(plant_parameters(nominal, perturbation), sort_keys=False)


class SensorModel:
    """The controller's sensors: maps the true (stance, q, q') at each control period to what the
    controller receives (noise and delay as in the module docstring).

    :meth:`sample` is called with the true state at the start of every period, in increasing period
    order (``Simulator.step`` does it); it is idempotent per period (the noise of a period is drawn
    once). :meth:`reading` returns the delayed noisy sample for the current period. :meth:`reset`
    restarts the generator from the seed and empties the pipeline."""

    def __init__(self, perturbation: PlantPerturbation = ZERO) -> None:
        self.perturbation = perturbation
        self.identity = perturbation.sensing_is_perfect
        self.reset()

    def reset(self) -> None:
        self._rng = np.random.default_rng(self.perturbation.seed)
        self._rng_imu = np.random.default_rng([self.perturbation.seed, 1])
        self._rng_gyro = np.random.default_rng([self.perturbation.seed, 2])
        # the standard normal draws of the periods to come, drawn ahead in blocks (rows: z_q (6), z_q' (6),
        # z_p, z_r): row i is what the i-th sampled period draws one by one (a generator's block of standard
        # normals is its draws one after another: tested), so a compiled loop can take rows too (noise_rows)
        self._z = np.empty((0, 14))
        self._zpos = 0
        self._samples: dict[int, tuple[int, np.ndarray, np.ndarray]] = {}
        self._pitch: dict[int, tuple[float, float]] = {}     # period -> (pitch [rad], pitch rate [rad/s])
        self._first: int | None = None
        self._last: int | None = None
        self._segment: int | None = None          # first sampled period of the current stance
        self._stance: int | None = None

    def sample(self, step: int, stance: int, q: np.ndarray, qd: np.ndarray, pitch: float | None = None,
               pitch_rate: float | None = None) -> tuple[int, np.ndarray, np.ndarray]:
        """The sensors' sample of period ``step`` (the true stance, q [rad], q' [rad/s] plus noise, angles
        quantised; ``pitch`` the true torso pitch [rad], None: q1 + q2 + q3, a flat stance foot; ``pitch_rate``
        its true rate [rad/s], None: q1' + q2' + q3'); a
        repeated call for the same period returns the stored sample. Raises ``ValueError`` for a period
        older than the last one sampled (the sensors cannot go back in time)."""
        if step in self._samples:
            return self._samples[step]
        if self._last is not None and step < self._last:
            raise ValueError(f"sensor sample for period {step} after period {self._last}")
        p = self.perturbation
        z = self.noise_rows(1)[0]
        self._zpos += 1
        zq, zqd = z[:6], z[6:12]
        qs = np.array(q, dtype=float)
        qds = np.array(qd, dtype=float)
        if p.noise_q > 0.0:
            qs = qs + p.noise_q * zq
        if p.noise_qd > 0.0:
            qds = qds + p.noise_qd * zqd
        if p.encoder_bits:
            step_q = p.encoder_step
            qs = step_q * np.round(qs / step_q)
        th = float(q[0] + q[1] + q[2]) if pitch is None else float(pitch)
        zp = float(z[12])
        if p.noise_pitch > 0.0:
            th += p.noise_pitch * zp
        rate = float(qd[0] + qd[1] + qd[2]) if pitch_rate is None else float(pitch_rate)
        zr = float(z[13])
        if p.noise_pitch_rate > 0.0:
            rate += p.noise_pitch_rate * zr
        self._pitch[step] = (th, rate)
        s = (int(stance), qs, qds)
        self._samples[step] = s
        if self._stance is None or int(stance) != self._stance:
            self._segment, self._stance = step, int(stance)
        if self._first is None:
            self._first = step
        self._last = step
        for old in [k for k in self._samples if k < step - p.delay]:
            del self._samples[old]
            del self._pitch[old]
        return s

    #: periods of noise drawn at once (one block costs about what 100 periods drawn one by one cost)
    BLOCK = 4096

    def noise_rows(self, n: int) -> np.ndarray:
        """The standard normal draws of the next ``n`` sampled periods at least (a view, rows as ``_z``:
        z_q (6), z_q' (6), z_p, z_r; the generators drawn ahead in blocks when fewer rows are left). They are
        not taken: :meth:`sample` takes one per period, :meth:`taken` records those a compiled loop used."""
        left = self._z.shape[0] - self._zpos
        if left < n:
            m = max(int(n) - left, self.BLOCK)
            block = np.empty((m, 14))
            block[:, :12] = self._rng.standard_normal((m, 12))
            block[:, 12] = self._rng_imu.standard_normal(m)
            block[:, 13] = self._rng_gyro.standard_normal(m)
            self._z = np.concatenate([self._z[self._zpos:], block])
            self._zpos = 0
        return self._z[self._zpos:]

    @property
    def compiled_noise(self) -> np.ndarray | None:
        """(noise_q [rad], noise_q' [rad/s], encoder step [rad] (0: none), noise_pitch [rad], noise_pitch_rate
        [rad/s]) for a compiled loop that samples as :meth:`sample` does; None where one cannot (a delay: the
        delay line is Python's; ideal sensors: nothing to sample)."""
        p = self.perturbation
        if self.identity or p.delay != 0:
            return None
        return np.array([p.noise_q, p.noise_qd, p.encoder_step, p.noise_pitch, p.noise_pitch_rate])

    def taken(self, n: int, last_step: int, stance: int) -> None:
        """A compiled loop sampled ``n`` > 0 periods, the last ``last_step`` in ``stance``, with the next ``n``
        rows of :meth:`noise_rows` (delay 0, :attr:`compiled_noise`): the rows are used and the bookkeeping
        is :meth:`sample`'s after them (the samples themselves are not kept: with no delay no later
        period reads them)."""
        if n <= 0:
            return
        self._zpos += int(n)
        self._samples.clear()
        self._pitch.clear()
        if self._stance is None or int(stance) != self._stance:
            # (one call of a compiled loop runs in one stance: an impact ends it)
            self._segment, self._stance = int(last_step) - int(n) + 1, int(stance)
        if self._first is None:
            self._first = int(last_step) - int(n) + 1
        self._last = int(last_step)

    def reading(self, step: int) -> tuple[int, np.ndarray, np.ndarray]:
        """What the controller receives at period ``step``: the sample of period max(step - delay, first
        sampled period), or with ``touchdown_delayed`` False max(step - delay, first sampled period of the
        current stance). The sample of ``step`` must have been taken."""
        if step not in self._samples:
            raise ValueError(f"no sensor sample for period {step}: sample() it first")
        k = max(step - self.perturbation.delay, self._first)
        if not self.perturbation.touchdown_delayed:
            k = max(k, self._segment)
        if k not in self._samples:
            raise ValueError(f"no sensor sample for period {k} (periods must be sampled one by one)")
        stance, q, qd = self._samples[k]
        return stance, q.copy(), qd.copy()

    def pitch_reading(self, step: int) -> float:
        """The IMU's torso pitch [rad] the controller receives at period ``step`` (the sample that
        :meth:`reading` returns the joints of)."""
        return self.imu_reading(step)[0]

    def imu_reading(self, step: int) -> tuple[float, float]:
        """The IMU's (torso pitch [rad], pitch rate [rad/s]) received at period ``step``: the sample that
        :meth:`reading` returns the joints of."""
        if step not in self._samples:
            raise ValueError(f"no sensor sample for period {step}: sample() it first")
        k = max(step - self.perturbation.delay, self._first)
        if not self.perturbation.touchdown_delayed:
            k = max(k, self._segment)
        return self._pitch[k]
