"""MJCF (MuJoCo's model format) of the planar biped, generated from the one description as the URDF is.

Pure Python, no ROS, no MuJoCo import (the text is plain XML; ``biped_sim.plant.mujoco`` compiles it).

The model mirrors ``description.make_urdf`` + the floating root of ``floating.FloatingModel``:

* body ``torso`` with its frame at the hip; root joints ``root_x`` (slide along x), ``root_z`` (slide along z),
  ``root_pitch`` (hinge about (0, -1, 0) at the hip), so ``qpos = qvel``-ordered ``[x_hip, z_hip, theta, lh,
  lk, la, rh, rk, ra]`` is ``floating``'s state vector (MuJoCo's ``qpos`` has no quaternion here);
* each leg: ``<side>_thigh`` at the hip, ``<side>_shin`` at ``-thigh.length`` along its z, ``<side>_foot`` at
  ``-shin.length``; hinges ``<side>_hip / _knee / _ankle`` about (0, -1, 0) (counter-clockwise in the sagittal
  view, DESIGN.md); inertials (mass, centre of mass on the link axis, I_yy; the other two axes equal, as the
  URDF) from ``robots/biped7/description.yaml``; no joint limits, damping or armature (the rigid plant has none);
* contact geometry: each foot a box from ``foot.l_min`` to ``foot.l_max`` along x (heel, toe), ``thickness``
  thick with its sole on the ankle line (``foot.ankle_height`` = 0), friction ``mu`` (``sole_points`` = 0); or
  (``sole_points`` = n >= 2) the sole as n spheres of diameter ``thickness`` whose lowest points lie on the ankle
  line at x = l_min + i (l_max - l_min) / (n - 1), i = 0..n-1 (heel and toe included): a box on a plane touches
  only at its corners, so its whole load sits on the heel and toe lines; the spheres spread it along the sole.
  Geom names ``<side>_foot_sole`` (the box, or the heel sphere) and ``<side>_foot_sole_<i>`` (i >= 1); the floor a plane at
  z = 0; massless capsules on torso, thighs and shins (the shin's ends ``shin_gap`` above the ankle) that only
  detect a body touching the floor. Robot geoms collide with the floor only (contype 0 / conaffinity 1,
  floor contype 1 / conaffinity 0);
* six ``motor`` actuators (gear 1, in the URDF joint order) with ``ctrlrange`` = the torque limits.

Every number comes from the description or from :class:`MjcfContact` (the plant fills it from
``config/simulator.yaml``); nothing here is a default.
"""
from __future__ import annotations

from dataclasses import dataclass

from biped_model.description import URDF_JOINTS, RobotDescription

ROOT_JOINTS = ("root_x", "root_z", "root_pitch")
FOOT_GEOMS = ("left_foot_sole", "right_foot_sole")
BODY_GEOMS = ("torso_capsule", "left_thigh_capsule", "left_shin_capsule", "right_thigh_capsule",
              "right_shin_capsule")
FLOOR_GEOM = "floor"


@dataclass(frozen=True)
class MjcfContact:
    """The engine's and the contact's settings (``config/simulator.yaml`` ``mujoco_*`` keys, units SI)."""

    timestep: float            # [s]
    integrator: str            # mjOption integrator name
    cone: str                  # "elliptic" | "pyramidal"
    tolerance: float           # Newton solver tolerance
    solref: tuple[float, float]                # (time constant [s], damping ratio)
    solimp: tuple[float, float, float]         # (dmin, dmax, width [m])
    foot_thickness: float      # [m]
    foot_width: float          # [m]
    body_radius: float         # [m]
    shin_gap: float            # [m]
    sole_points: int = 0       # 0: the sole is the box; n >= 2: n contact spheres from heel to toe


def foot_geom_names(side: str, sole_points: int) -> tuple[str, ...]:
    """The collision geoms of one foot (``side`` "left" | "right"), heel first (module docstring)."""
    base = f"{side}_foot_sole"
    return (base,) + tuple(f"{base}_{i}" for i in range(1, sole_points))


def _f(v: float) -> str:
    return repr(float(v))


def _inertial(mass: float, com_x: float, com_z: float, iyy: float) -> str:
    return (f'<inertial pos="{_f(com_x)} 0 {_f(com_z)}" mass="{_f(mass)}" '
            f'diaginertia="{_f(iyy)} {_f(iyy)} {_f(iyy)}"/>')


def make_mjcf(desc: RobotDescription, contact: MjcfContact) -> str:
    """The MJCF text of the biped (see the module docstring for the layout, frames and signs)."""
    t, th, sh, ft = desc.torso, desc.thigh, desc.shin, desc.foot
    c = contact
    r = c.body_radius
    sole_x = 0.5 * (ft.l_min + ft.l_max)
    half = (0.5 * (ft.l_max - ft.l_min), 0.5 * c.foot_width, 0.5 * c.foot_thickness)
    detect = 'contype="0" conaffinity="1" mass="0" group="3"'
    out = [
        '<mujoco model="planar_biped">',
        '  <compiler angle="radian" inertiafromgeom="false" autolimits="true"/>',
        f'  <option timestep="{_f(c.timestep)}" integrator="{c.integrator}" cone="{c.cone}" solver="Newton" '
        f'tolerance="{_f(c.tolerance)}" gravity="0 0 {_f(-desc.gravity)}" jacobian="dense"/>',
        '  <default>',
        f'    <geom solref="{_f(c.solref[0])} {_f(c.solref[1])}" '
        f'solimp="{_f(c.solimp[0])} {_f(c.solimp[1])} {_f(c.solimp[2])}" friction="{_f(desc.mu)} 0 0" condim="3"/>',
        '    <joint axis="0 -1 0" damping="0" armature="0" limited="false"/>',
        '  </default>',
        '  <worldbody>',
        f'    <geom name="{FLOOR_GEOM}" type="plane" size="0 0 1" contype="1" conaffinity="0"/>',
        '    <body name="torso" pos="0 0 0">',
        '      <joint name="root_x" type="slide" axis="1 0 0"/>',
        '      <joint name="root_z" type="slide" axis="0 0 1"/>',
        '      <joint name="root_pitch" type="hinge" axis="0 -1 0"/>',
        f'      {_inertial(t.mass, 0.0, t.com, t.inertia)}',
        f'      <geom name="torso_capsule" type="capsule" fromto="0 0 0 0 0 {_f(t.length)}" size="{_f(r)}" {detect}/>',
    ]
    if c.sole_points and (not isinstance(c.sole_points, int) or c.sole_points < 2):
        raise ValueError(f"sole_points must be 0 (a box) or an integer >= 2, got {c.sole_points!r}")
    for side in ("left", "right"):
        j_hip, j_knee, j_ankle = (n for n in URDF_JOINTS if n.startswith(side))
        if c.sole_points:
            n = c.sole_points
            sole = [f'            <geom name="{name}" type="sphere" '
                    f'pos="{_f(ft.l_min + i * (ft.l_max - ft.l_min) / (n - 1))} 0 {_f(-ft.ankle_height + half[2])}" '
                    f'size="{_f(half[2])}" contype="0" conaffinity="1" mass="0"/>'
                    for i, name in enumerate(foot_geom_names(side, n))]
        else:
            sole = [f'            <geom name="{side}_foot_sole" type="box" pos="{_f(sole_x)} 0 {_f(-ft.ankle_height + half[2])}" '
                    f'size="{_f(half[0])} {_f(half[1])} {_f(half[2])}" contype="0" conaffinity="1" mass="0"/>']
        out += [
            f'      <body name="{side}_thigh" pos="0 0 0">',
            f'        <joint name="{j_hip}" type="hinge"/>',
            f'        {_inertial(th.mass, 0.0, -th.com, th.inertia)}',
            f'        <geom name="{side}_thigh_capsule" type="capsule" fromto="0 0 0 0 0 {_f(-th.length)}" '
            f'size="{_f(r)}" {detect}/>',
            f'        <body name="{side}_shin" pos="0 0 {_f(-th.length)}">',
            f'          <joint name="{j_knee}" type="hinge"/>',
            f'          {_inertial(sh.mass, 0.0, -sh.com, sh.inertia)}',
            f'          <geom name="{side}_shin_capsule" type="capsule" fromto="0 0 0 0 0 {_f(-(sh.length - c.shin_gap))}" '
            f'size="{_f(r)}" {detect}/>',
            f'          <body name="{side}_foot" pos="0 0 {_f(-sh.length)}">',
            f'            <joint name="{j_ankle}" type="hinge"/>',
            f'            {_inertial(ft.mass, ft.com_forward, -ft.ankle_height, ft.inertia)}',
            *sole,
            '          </body>',
            '        </body>',
            '      </body>',
        ]
    out += ['    </body>', '  </worldbody>', '  <actuator>']
    for name in URDF_JOINTS:
        lim = desc.torque_max[0 if "ankle" in name else 1 if "knee" in name else 2]
        out.append(f'    <motor name="{name}_motor" joint="{name}" gear="1" ctrlrange="{_f(-lim)} {_f(lim)}"/>')
    out += ['  </actuator>', '</mujoco>', '']
    return "\n".join(out)
