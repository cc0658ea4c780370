"""robots/biped7/description.yaml and the generated URDF: reasons, the paper's values, validation errors naming
the key, and the URDF read back by Pinocchio and by an XML parser."""
from __future__ import annotations

import copy
import math
import xml.etree.ElementTree as ET

import numpy as np
import pinocchio as pin
import pytest
import yaml

from helpers import CONFIG, assert_close

from biped_model.description import (
    URDF_JOINTS,
    DescriptionError,
    load_description,
    make_urdf,
    parse_description,
)


@pytest.fixture()
def tree() -> dict:
    with open(CONFIG, encoding="utf-8") as fh:
        return yaml.safe_load(fh)


@pytest.fixture(scope="module")
def desc():
    return load_description(CONFIG)


def leaves(node, prefix=""):
    """(dotted key, leaf) for every leaf: a {value, reason} mapping, or a bare scalar (itself an error)."""
    for k, v in node.items():
        key = f"{prefix}.{k}" if prefix else str(k)
        if isinstance(v, dict) and "value" not in v:
            yield from leaves(v, key)
        else:
            yield key, v


def test_every_leaf_has_a_reason(tree):
    found = list(leaves(tree))
    assert len(found) >= 25, [k for k, _ in found]
    for key, leaf in found:
        assert isinstance(leaf, dict), f"{key}: bare value {leaf!r} without a reason"
        assert set(leaf) == {"value", "reason"}, f"{key}: keys {sorted(leaf)}"
        assert isinstance(leaf["reason"], str) and leaf["reason"].strip(), f"{key}: empty reason"
        v = leaf["value"]
        assert isinstance(v, (int, float)) and not isinstance(v, bool) and math.isfinite(v), f"{key}: {v!r}"


def test_paper_values(desc):
    assert (desc.torso.mass, desc.thigh.mass, desc.shin.mass) == (20.0, 6.0, 4.0)
    assert (desc.torso.length, desc.thigh.length, desc.shin.length) == (0.625, 0.4, 0.4)
    assert (desc.foot.l_min, desc.foot.l_max) == (-0.1, 0.1)
    assert desc.foot.ankle_height == 0.0 and desc.foot.com_forward == 0.0
    assert_close(desc.total_mass, 20 + 2 * (6 + 4) + 2 * desc.foot.mass, 1e-12, "total mass")
    assert_close(desc.leg_length, 0.8, 1e-15, "leg length")
    lo, hi = desc.torque_limits()
    assert_close(lo, -np.array(hi), 0.0, "symmetric torque limits")
    assert desc.torque_max[0] == desc.torque_max[5] and desc.torque_max[1] == desc.torque_max[4]
    assert desc.torque_max[2] == desc.torque_max[3]


def test_rod_inertias_match_their_reasons(desc):
    for link in (desc.torso, desc.thigh, desc.shin):
        assert_close(link.inertia, link.mass * link.length**2 / 12, 1e-12, "slender-rod inertia")
        assert_close(link.com, link.length / 2, 1e-15, "mid-length centre of mass")


def test_parse_accepts_the_file_as_is(tree, desc):
    d = parse_description(tree)
    assert d.torso == desc.torso and d.foot == desc.foot and d.torque_max == desc.torque_max


def _expect_error(tree, *keys):
    with pytest.raises(DescriptionError) as ei:
        parse_description(tree)
    msg = str(ei.value)
    for k in keys:
        assert k in msg, f"error message {msg!r} does not name {k!r}"
    return msg


def test_missing_key_is_named(tree):
    del tree["thigh"]["mass"]
    _expect_error(tree, "thigh.mass")


def test_missing_section_is_named(tree):
    del tree["friction"]
    _expect_error(tree, "friction")


@pytest.mark.parametrize(
    "section,key,bad",
    [
        ("shin", "length", "long"),
        ("torso", "inertia", float("nan")),
        ("foot", "l_max", float("inf")),
        ("thigh", "com_from_proximal", None),
        ("torso", "mass", True),
    ],
)
def test_non_numeric_values_are_named(tree, section, key, bad):
    tree[section][key]["value"] = bad
    _expect_error(tree, f"{section}.{key}")


def test_negative_mass_is_named(tree):
    tree["shin"]["mass"]["value"] = -4.0
    _expect_error(tree, "shin.mass")


def test_zero_gravity_is_rejected(tree):
    tree["gravity"]["value"] = 0.0
    _expect_error(tree, "gravity")


def test_ankle_height_must_be_zero(tree):
    tree["foot"]["ankle_height"]["value"] = 0.03
    _expect_error(tree, "ankle_height")


def test_empty_reason_is_named(tree):
    tree["torso"]["length"]["reason"] = "  "
    _expect_error(tree, "torso.length")


def test_value_without_reason_is_named(tree):
    tree["friction"]["mu"] = 0.7
    _expect_error(tree, "friction.mu")


def test_inconsistent_sole_is_rejected(tree):
    tree["foot"]["l_min"]["value"] = 0.05
    _expect_error(tree, "l_min")


def test_missing_file_raises(tmp_path):
    with pytest.raises(DescriptionError):
        load_description(tmp_path / "nope.yaml")


# ------------------------------------------------------------------------------------- URDF
def test_urdf_parses_with_pinocchio_and_has_the_total_mass(desc):
    model = pin.buildModelFromXML(make_urdf(desc))
    assert model.nq == 6 and model.nv == 6
    assert tuple(model.names[1:]) == URDF_JOINTS
    mass = sum(inertia.mass for inertia in model.inertias)
    assert_close(mass, desc.total_mass, 1e-12, "URDF total mass")
    data = model.createData()
    # Upright at zero angles: CoM relative to the hip is the mass-weighted sum of link centres. (A
    # fixed-base model merges the torso into the universe, which centerOfMass leaves out: use a free flyer.)
    ff = pin.buildModelFromXML(make_urdf(desc), pin.JointModelFreeFlyer())
    com = pin.centerOfMass(ff, ff.createData(), pin.neutral(ff))
    t, th, sh = desc.torso, desc.thigh, desc.shin
    z = (t.mass * t.com - 2 * th.mass * th.com - 2 * sh.mass * (th.length + sh.com)
         - 2 * desc.foot.mass * desc.leg_length) / desc.total_mass
    assert_close(com[[0, 2]], [0.0, z], 1e-12, "URDF CoM at zero posture (hip frame)")
    # Feet at the leg length below the hip at zero angles; a positive hip angle swings the leg forwards.
    for side in ("left", "right"):
        fid = model.getFrameId(f"{side}_foot")
        pin.framesForwardKinematics(model, data, np.zeros(6))
        assert_close(data.oMf[fid].translation[[0, 2]], [0.0, -desc.leg_length], 1e-12, f"{side} foot")
    qj = np.zeros(6)
    qj[0] = 0.3  # left hip: thigh ccw w.r.t. torso (axis 0 -1 0) -> foot forwards (+x)
    pin.framesForwardKinematics(model, data, qj)
    fpos = data.oMf[model.getFrameId("left_foot")].translation
    assert_close(fpos[[0, 2]], [desc.leg_length * math.sin(0.3), -desc.leg_length * math.cos(0.3)], 1e-12,
                 "positive hip angle = counter-clockwise")


def test_urdf_joints_and_axes(desc):
    root = ET.fromstring(make_urdf(desc))
    joints = root.findall("joint")
    assert [j.get("name") for j in joints] == list(URDF_JOINTS) or sorted(j.get("name") for j in joints) == sorted(
        URDF_JOINTS
    )
    assert len(joints) == 6
    for j in joints:
        assert j.get("type") == "revolute", j.get("name")
        axis = [float(c) for c in j.find("axis").get("xyz").split()]
        assert axis == [0.0, -1.0, 0.0], (j.get("name"), axis)
        lim = j.find("limit")
        lo, hi = float(lim.get("lower")), float(lim.get("upper"))
        assert lo < hi
        if "knee" in j.get("name"):  # URDF knee = -(paper flexion): range [-knee_max, -knee_min]
            assert (lo, hi) == (-desc.knee_max_flexion, -desc.knee_min_flexion)
    links = {lk.get("name") for lk in root.findall("link")}
    assert links == {"torso"} | {f"{s}_{p}" for s in ("left", "right") for p in ("thigh", "shin", "foot")}
    masses = sorted(float(lk.find("inertial/mass").get("value")) for lk in root.findall("link"))
    assert_close(sum(masses), desc.total_mass, 1e-12, "sum of URDF link masses")


def test_urdf_reflects_a_modified_description(tree):
    t2 = copy.deepcopy(tree)
    t2["torso"]["mass"]["value"] = 25.0
    d2 = parse_description(t2)
    model = pin.buildModelFromXML(make_urdf(d2))
    assert_close(sum(i.mass for i in model.inertias), d2.total_mass, 1e-12, "modified total mass")
    assert_close(d2.total_mass, 46.0, 1e-12, "25 + 2 (6 + 4 + 0.5)")
