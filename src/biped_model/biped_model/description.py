"""Robot description: load ``robots/biped7/description.yaml`` and generate the URDF.

Pure Python (no ROS). The YAML file holds every physical value as ``{value, reason}``; this module
turns it into frozen dataclasses, checks it, and writes the URDF that both Pinocchio (simulator) and
Foxglove (3-D view) read.

Frames and signs (see DESIGN.md): world x forward, z up, motion in the x-z plane; every revolute axis
is (0, -1, 0) so positive angles are counter-clockwise in the sagittal view. The URDF is rooted at the
torso, whose frame origin is the hip; legs hang down (-z) at zero angles; each ankle frame lies on
the sole line (ankle height 0, required by the paper's eq. (7)).
"""
from __future__ import annotations

import math
import os
from dataclasses import dataclass
from pathlib import Path
from typing import Any

from biped_model.finite import finite_number
from biped_model.settings import SettingsError, default_robot_dir, load_yaml_tree

JOINT_AXIS = (0.0, -1.0, 0.0)
URDF_JOINTS = ("left_hip", "left_knee", "left_ankle", "right_hip", "right_knee", "right_ankle")
# Names of the paper's joints q1..q6 in the controller's view (stance ankle first).
PAPER_JOINTS = ("stance_ankle", "stance_knee", "stance_hip", "swing_hip", "swing_knee", "swing_ankle")
LEFT, RIGHT = 0, 1


class DescriptionError(ValueError):
    """The robot description file is missing a value, has a wrong type, or is physically inconsistent."""


@dataclass(frozen=True)
class Link:
    """A straight link: length [m], mass [kg], centre of mass at ``com`` [m] from its proximal joint
    along the link, rotational inertia ``inertia`` [kg m^2] about its centre of mass (normal axis)."""

    length: float
    mass: float
    com: float
    inertia: float


@dataclass(frozen=True)
class Foot:
    """Foot: sole from ``l_min`` to ``l_max`` [m] along x around the ankle; the ankle is on the sole line."""

    length: float
    mass: float
    inertia: float
    ankle_height: float
    com_forward: float
    l_min: float
    l_max: float


@dataclass(frozen=True)
class RobotDescription:
    """Everything physical about the biped. ``torque_max[i]`` bounds |Gamma_i| for the paper's q1..q6."""

    gravity: float
    torso: Link
    thigh: Link
    shin: Link
    foot: Foot
    mu: float
    torque_max: tuple[float, float, float, float, float, float]
    knee_min_flexion: float
    knee_max_flexion: float
    source: str = ""

    @property
    def total_mass(self) -> float:
        """M [kg], the whole robot including both feet."""
        return self.torso.mass + 2 * (self.thigh.mass + self.shin.mass + self.foot.mass)

    @property
    def leg_length(self) -> float:
        return self.thigh.length + self.shin.length

    def torque_limits(self) -> tuple[list[float], list[float]]:
        """(Gamma_m, Gamma_M) for q1..q6 [N m], eq. (9)."""
        upper = list(self.torque_max)
        return [-u for u in upper], upper


def _value(tree: dict[str, Any], *keys: str) -> float:
    node: Any = tree
    path = ".".join(keys)
    for k in keys:
        if not isinstance(node, dict) or k not in node:
            raise DescriptionError(f"biped description: missing '{path}'")
        node = node[k]
    if not isinstance(node, dict) or "value" not in node or "reason" not in node:
        raise DescriptionError(f"biped description: '{path}' must be {{value, reason}}")
    if not str(node["reason"]).strip():
        raise DescriptionError(f"biped description: '{path}' has an empty reason")
    v = node["value"]
    return finite_number(v, path, error=DescriptionError,
                         message=f"biped description: '{path}' must be a finite number, got {v!r}")


def _positive(name: str, v: float) -> float:
    if v <= 0:
        raise DescriptionError(f"biped description: '{name}' must be > 0, got {v}")
    return v


def _link(tree: dict[str, Any], name: str) -> Link:
    length = _positive(f"{name}.length", _value(tree, name, "length"))
    mass = _positive(f"{name}.mass", _value(tree, name, "mass"))
    com = _value(tree, name, "com_from_proximal")
    if not 0.0 <= com <= length:
        raise DescriptionError(f"biped description: '{name}.com_from_proximal' must lie in [0, {length}], got {com}")
    inertia = _positive(f"{name}.inertia", _value(tree, name, "inertia"))
    return Link(length, mass, com, inertia)


#: every field of a description: group -> its leaves (None: the group is itself a {value, reason} leaf)
FIELDS: dict[str, tuple[str, ...] | None] = {
    "gravity": None,
    "torso": ("length", "mass", "com_from_proximal", "inertia"),
    "thigh": ("length", "mass", "com_from_proximal", "inertia"),
    "shin": ("length", "mass", "com_from_proximal", "inertia"),
    "foot": ("length", "mass", "inertia", "ankle_height", "com_forward", "l_min", "l_max"),
    "friction": ("mu",),
    "torque_limits": ("ankle", "knee", "hip"),
    "joint_limits": ("knee_min_flexion", "knee_max_flexion"),
}

#: hip height over the stance ankle [leg lengths] of the posture the torque limits must hold (standing_torques)
STANDING_HIP_HEIGHT = 0.925


def _unknown_fields(tree: dict[str, Any]) -> None:
    for k, v in tree.items():
        if k not in FIELDS:
            raise DescriptionError(f"biped description: unknown field '{k}' (fields: {', '.join(FIELDS)})")
        leaves = FIELDS[k]
        if leaves is not None and isinstance(v, dict):
            for sub in v:
                if sub not in leaves:
                    raise DescriptionError(f"biped description: unknown field '{k}.{sub}' "
                                           f"(fields of {k}: {', '.join(leaves)})")


def standing_torques(desc: "RobotDescription") -> tuple[float, float, float]:
    """Static torques [N m] (ankle, knee, hip) of the stance leg in the posture a robot must be able to hold:
    single support, the hip :data:`STANDING_HIP_HEIGHT` leg lengths straight above the stance ankle (the
    knee bent forward, the height of the gait generation's initial guess for the default robot: 0.74 m of
    0.8 m), torso upright, swing leg hanging straight under the hip. Gravity only, frames of the sagittal
    plane (x forward, z up). The centre of mass of everything above a joint is over the hip line except the
    stance thigh's (and, for the ankle, the shin's), so the ankle and hip torques are small and the knee's
    is the one that binds: the weight above the knee times the knee's forward offset from the hip line."""
    a, b = desc.thigh.length, desc.shin.length
    h = STANDING_HIP_HEIGHT * (a + b)
    # knee position (x forward of the ankle-hip line): the triangle ankle-knee-hip with sides b, a, h
    zk = (h * h + b * b - a * a) / (2.0 * h)          # knee height above the ankle
    xk = math.sqrt(max(b * b - zk * zk, 0.0))
    g = desc.gravity
    swing = desc.thigh.mass + desc.shin.mass + desc.foot.mass
    # about the knee: torso + swing leg on the hip line (x = 0), stance thigh's centre of mass on the thigh
    thigh_com_x = xk * (1.0 - desc.thigh.com / a)      # the thigh runs from the hip (x 0) to the knee (x xk)
    knee = g * ((desc.torso.mass + swing) * xk + desc.thigh.mass * (xk - thigh_com_x))
    shin_com_x = xk * (desc.shin.com / b)              # the shin runs from the knee (x xk) down to the ankle (x 0)
    ankle = g * desc.shin.mass * shin_com_x + g * desc.thigh.mass * thigh_com_x
    hip = 0.0
    return ankle, knee, hip


def parse_description(tree: dict[str, Any], source: str = "") -> RobotDescription:
    """Validate a parsed YAML tree and build the description. Raises DescriptionError naming the key:
    a missing or unknown field, a value that is not a finite number, a mass, length or inertia <= 0, a
    torque limit that cannot hold the standing posture of :func:`standing_torques`."""
    if not isinstance(tree, dict):
        raise DescriptionError("biped description: top level must be a mapping")
    _unknown_fields(tree)
    foot = Foot(
        length=_positive("foot.length", _value(tree, "foot", "length")),
        mass=_positive("foot.mass", _value(tree, "foot", "mass")),
        inertia=_positive("foot.inertia", _value(tree, "foot", "inertia")),
        ankle_height=_value(tree, "foot", "ankle_height"),
        com_forward=_value(tree, "foot", "com_forward"),
        l_min=_value(tree, "foot", "l_min"),
        l_max=_value(tree, "foot", "l_max"),
    )
    if foot.ankle_height != 0.0 or foot.com_forward != 0.0:
        raise DescriptionError(
            "biped description: eq. (7) Gamma_1 = l R_y needs foot.ankle_height = 0 and foot.com_forward = 0"
        )
    if not foot.l_min < 0.0 < foot.l_max:
        raise DescriptionError("biped description: need foot.l_min < 0 < foot.l_max")
    if foot.l_max - foot.l_min > foot.length + 1e-12:
        raise DescriptionError("biped description: [foot.l_min, foot.l_max] exceeds foot.length")
    ankle = _positive("torque_limits.ankle", _value(tree, "torque_limits", "ankle"))
    knee = _positive("torque_limits.knee", _value(tree, "torque_limits", "knee"))
    hip = _positive("torque_limits.hip", _value(tree, "torque_limits", "hip"))
    kmin = _value(tree, "joint_limits", "knee_min_flexion")
    kmax = _value(tree, "joint_limits", "knee_max_flexion")
    if not kmin < kmax:
        raise DescriptionError("biped description: need joint_limits.knee_min_flexion < knee_max_flexion")
    desc = RobotDescription(
        gravity=_positive("gravity", _value(tree, "gravity")),
        torso=_link(tree, "torso"),
        thigh=_link(tree, "thigh"),
        shin=_link(tree, "shin"),
        foot=foot,
        mu=_positive("friction.mu", _value(tree, "friction", "mu")),
        torque_max=(ankle, knee, hip, hip, knee, ankle),
        knee_min_flexion=kmin,
        knee_max_flexion=kmax,
        source=source,
    )
    for name, need, have in zip(("ankle", "knee", "hip"), standing_torques(desc), (ankle, knee, hip)):
        if have < need:
            raise DescriptionError(f"biped description: 'torque_limits.{name}' = {have:g} N m cannot hold the robot "
                                   f"standing ({need:.1f} N m on one leg, hip at {STANDING_HIP_HEIGHT} leg lengths)")
    return desc


def load_description(path: str | os.PathLike[str] | None = None) -> RobotDescription:
    """Load and validate ``robots/biped7/description.yaml`` (or ``path``)."""
    p = Path(path) if path is not None else default_robot_dir() / "description.yaml"
    if not p.is_file():
        raise DescriptionError(f"biped description: file not found: {p}")
    try:
        tree = load_yaml_tree(p)
    except SettingsError as exc:
        raise DescriptionError(f"biped description: {exc}") from exc
    return parse_description(tree, source=str(p))


def _inertial(mass: float, com_z: float, iyy: float, com_x: float = 0.0) -> str:
    # Only I_yy matters for planar motion; the other two axes get the same value so the 3-D tensor is
    # positive definite (Pinocchio and Foxglove both require a physical tensor).
    return (
        f'    <inertial>\n      <origin xyz="{com_x!r} 0 {com_z!r}" rpy="0 0 0"/>\n'
        f'      <mass value="{mass!r}"/>\n'
        f'      <inertia ixx="{iyy!r}" ixy="0" ixz="0" iyy="{iyy!r}" iyz="0" izz="{iyy!r}"/>\n    </inertial>\n'
    )


def _segment_visual(z0: float, z1: float, radius: float, rgba: str) -> str:
    length = abs(z1 - z0)
    mid = 0.5 * (z0 + z1)
    return (
        f'    <visual>\n      <origin xyz="0 0 {mid!r}" rpy="0 0 0"/>\n'
        f'      <geometry><cylinder radius="{radius}" length="{length!r}"/></geometry>\n'
        f'      <material name="c{rgba.replace(" ", "_")}"><color rgba="{rgba}"/></material>\n    </visual>\n'
    )


def make_urdf(desc: RobotDescription, hip_offset_y: float = 0.08) -> str:
    """URDF of the biped, rooted at the torso (frame origin at the hip).

    ``hip_offset_y`` separates the legs sideways for display only: all axes are parallel to y and
    gravity is along -z, so a y offset does not change the sagittal dynamics.
    """
    t, th, sh, ft = desc.torso, desc.thigh, desc.shin, desc.foot
    out = ['<?xml version="1.0"?>\n<robot name="planar_biped">\n']
    out.append('  <link name="torso">\n')
    out.append(_inertial(t.mass, t.com, t.inertia))
    out.append(_segment_visual(0.0, t.length, 0.05, "0.2 0.4 0.8 1"))
    out.append("  </link>\n")
    for side, sign, color in (("left", 1.0, "0.85 0.45 0.1 1"), ("right", -1.0, "0.3 0.7 0.3 1")):
        y = sign * hip_offset_y
        out.append(f'  <link name="{side}_thigh">\n')
        out.append(_inertial(th.mass, -th.com, th.inertia))
        out.append(_segment_visual(-th.length, 0.0, 0.035, color))
        out.append("  </link>\n")
        out.append(f'  <link name="{side}_shin">\n')
        out.append(_inertial(sh.mass, -sh.com, sh.inertia))
        out.append(_segment_visual(-sh.length, 0.0, 0.03, color))
        out.append("  </link>\n")
        out.append(f'  <link name="{side}_foot">\n')
        out.append(_inertial(ft.mass, 0.0, ft.inertia, com_x=ft.com_forward))
        cx = 0.5 * (ft.l_min + ft.l_max)
        out.append(
            f'    <visual>\n      <origin xyz="{cx!r} 0 -0.01" rpy="0 0 0"/>\n'
            f'      <geometry><box size="{ft.l_max - ft.l_min!r} 0.08 0.02"/></geometry>\n'
            f'      <material name="foot_{side}"><color rgba="{color}"/></material>\n    </visual>\n'
        )
        out.append("  </link>\n")
        joints = (
            (f"{side}_hip", "torso", f"{side}_thigh", f"0 {y!r} 0"),
            (f"{side}_knee", f"{side}_thigh", f"{side}_shin", f"0 0 {-th.length!r}"),
            (f"{side}_ankle", f"{side}_shin", f"{side}_foot", f"0 0 {-sh.length!r}"),
        )
        for name, parent, child, xyz in joints:
            lim = desc.torque_max[0 if "ankle" in name else 1 if "knee" in name else 2]
            if "knee" in name:
                lower, upper = -desc.knee_max_flexion, -desc.knee_min_flexion
            else:
                lower, upper = -math.pi, math.pi
            out.append(
                f'  <joint name="{name}" type="revolute">\n    <parent link="{parent}"/>\n    <child link="{child}"/>\n'
                f'    <origin xyz="{xyz}" rpy="0 0 0"/>\n    <axis xyz="0 -1 0"/>\n'
                f'    <limit lower="{lower!r}" upper="{upper!r}" effort="{lim!r}" velocity="20"/>\n  </joint>\n'
            )
    out.append("</robot>\n")
    return "".join(out)
