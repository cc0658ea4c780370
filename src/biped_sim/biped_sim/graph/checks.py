"""Start-up consistency checks of the robot files (pure: no ROS import), used by the nodes.

- :func:`check_family_matches_description`: the gait family was generated for this robot: its
  first posture q_d(p_d, 0) is the double support of the preferred stride, i.e. with the stance
  foot flat at x = 0 the swing ankle lies on the ground, flat, at x = -p_d (within 1 mm / 1 mrad).
  A family of another robot (other link lengths) fails this.
- :func:`check_urdf_joints`: a URDF text has exactly the joints the simulator drives
  (``description.URDF_JOINTS``), each revolute about (0, -1, 0).
"""

from __future__ import annotations

import xml.etree.ElementTree as ET

import numpy as np

from biped_model.description import LEFT, RIGHT, URDF_JOINTS

TOLERANCE = 1e-3


class RobotFilesError(ValueError):
    """The description, URDF and gait family do not fit together, or one cannot be read; ``field`` names
    the node parameter that points at the offending file (``description_path``, ``gait_family_path``)."""

    def __init__(self, message: str, field: str = "") -> None:
        super().__init__(message)
        self.field = field


def load_robot_files(description_path: str = "", gait_family_path: str = "", robot: str = ""):
    """(RobotDescription, GaitFamily) of the robot ``robot`` (a name under ``robots/`` or a path; '' = the
    default robot, robots/biped7), its description and family replaced by ``description_path`` and
    ``gait_family_path`` when given, checked against each other (the robot's own family also against its
    description's stamp, ``biped_model.robot``); :class:`RobotFilesError` names the parameter at fault."""
    from biped_model.description import DescriptionError, load_description
    from biped_model.gait_family import GaitFamily, GaitFamilyError
    from biped_model.robot import RobotError, resolve_robot
    try:
        r = resolve_robot(robot or None)
    except RobotError as exc:
        raise RobotFilesError(str(exc), "robot") from exc
    if not description_path and not gait_family_path:
        try:
            r.description()
        except RobotError as exc:
            raise RobotFilesError(str(exc), "robot") from exc
        try:
            r.check_stamp()
        except RobotError as exc:
            raise RobotFilesError(str(exc), "robot") from exc
    try:
        desc = load_description(description_path or r.description_path)
    except (DescriptionError, OSError, ValueError) as exc:
        raise RobotFilesError(str(exc), "description_path") from exc
    try:
        family = GaitFamily.load(gait_family_path or r.family_path)
    except (GaitFamilyError, OSError) as exc:
        raise RobotFilesError(str(exc), "gait_family_path") from exc
    try:
        check_family_matches_description(desc, family)
    except RobotFilesError as exc:
        raise RobotFilesError(str(exc), "gait_family_path") from exc
    return desc, family


def check_family_matches_description(desc, family) -> None:
    from biped_model.floating import FloatingModel
    g = family.evaluate(family.p_d, 0.0)
    fm = FloatingModel(desc)
    x, _v = fm.state_from_paper(np.asarray(g.q, float), np.asarray(g.dq_dtau, float), LEFT, 0.0)
    px, pz, pitch = fm.foot_pose(x, RIGHT)
    err = max(abs(px + family.p_d), abs(pz), abs(pitch))
    if not np.isfinite(err) or err > TOLERANCE:
        raise RobotFilesError(
            f'gait family does not match the robot description {getattr(desc, "source", "")}: its first '
            f'posture puts the swing ankle at (x, z, pitch) = ({px:.4f}, {pz:.4f}, {pitch:.4f}), expected '
            f'({-family.p_d:.4f}, 0, 0) within {TOLERANCE}')


def check_urdf_joints(urdf: str) -> None:
    try:
        root = ET.fromstring(urdf)
    except ET.ParseError as exc:
        raise RobotFilesError(f'URDF does not parse: {exc}') from exc
    joints = {j.get('name'): j for j in root.iter('joint')}
    names = set(joints)
    expected = set(URDF_JOINTS)
    if names != expected:
        raise RobotFilesError(f'URDF joints {sorted(names)} are not the simulator\'s {sorted(expected)} '
                              f'(missing {sorted(expected - names)}, unknown {sorted(names - expected)})')
    for name, j in joints.items():
        axis = j.find('axis')
        xyz = [float(v) for v in axis.get('xyz').split()] if axis is not None else None
        if j.get('type') != 'revolute' or xyz is None or not np.allclose(xyz, (0.0, -1.0, 0.0)):
            raise RobotFilesError(f'URDF joint {name}: must be revolute about (0, -1, 0), got type '
                                  f'{j.get("type")!r}, axis {xyz}')
