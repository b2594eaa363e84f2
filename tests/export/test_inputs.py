"""Bad inputs give InputErrors that name what is wrong; a fixed joint exports as a fixed link."""

from __future__ import annotations

import xml.etree.ElementTree as ET

import numpy as np
import pytest
import trimesh

from artitwin_core import InputError
from artitwin_core.capture import Capture
from artitwin_core.export import export_mjcf, export_urdf, fuse_part_mesh
from artitwin_core.joints import Joint

BOX = trimesh.creation.box(extents=[0.2, 0.2, 0.2])
Z = np.zeros(3)


def _capture(t: int = 2) -> Capture:
    return Capture(
        rgb=np.zeros((t, 8, 8, 3), np.uint8), depth=np.ones((t, 8, 8), np.float32), confidence=None,
        rgb_intrinsics=np.tile([8.0, 8, 4, 4], (t, 1)), depth_intrinsics=np.tile([8.0, 8, 4, 4], (t, 1)),
        world_from_camera=np.tile(np.eye(4), (t, 1, 1)), timestamps=np.arange(t, dtype=float),
        frame_ids=np.arange(t),
    )


def _joint(kind="revolute", axis=(0.0, 1, 0), q_range=(0.0, 1.0)) -> Joint:
    return Joint(kind, np.asarray(axis, float), Z, Z, np.asarray(q_range, float), Z, Z)


@pytest.mark.parametrize(("kwargs", "words"), [
    ({"masks": np.ones((3, 8, 8), bool)}, "3 masks"),
    ({"masks": None, "world_from_closed": np.tile(np.eye(4), (5, 1, 1))}, "5 poses"),
    ({"masks": None, "voxel_m": 0.0}, "voxel_m"),
])
def test_fuse_rejects_mismatched_inputs(kwargs, words):
    masks = kwargs.pop("masks")
    with pytest.raises(InputError, match=words):
        fuse_part_mesh(_capture(), masks, **kwargs)


def test_fuse_of_nothing_is_an_empty_mesh():
    mesh = fuse_part_mesh(_capture(), np.zeros((2, 8, 8), bool))
    assert len(mesh.faces) == 0


@pytest.mark.parametrize(("joint", "words"), [
    (_joint(q_range=(1.0, 0.0)), "q_range"),
    (_joint(axis=(0.0, 0, 0)), "axis"),
    (_joint(kind="ball"), "joint type"),
])
def test_export_rejects_bad_joints(tmp_path, joint, words):
    with pytest.raises(InputError, match=words):
        export_urdf(tmp_path, BOX, [("door", joint, BOX, [BOX])], base_collision=[BOX])


def test_export_rejects_empty_part_mesh(tmp_path):
    empty = trimesh.Trimesh(np.zeros((0, 3)), np.zeros((0, 3), int))
    with pytest.raises(InputError, match="empty mesh"):
        export_urdf(tmp_path, BOX, [("door", _joint(), empty, [BOX])], base_collision=[BOX])


def test_fixed_joint_exports_and_loads(tmp_path):
    mujoco = pytest.importorskip("mujoco", reason="mujoco not installed")
    pybullet = pytest.importorskip("pybullet", reason="pybullet not installed")
    parts = [("panel", _joint(kind="fixed"), BOX, [BOX])]
    urdf = export_urdf(tmp_path, BOX, parts, base_collision=[BOX], sim_from_canonical=None)
    mjcf = export_mjcf(tmp_path, BOX, parts, base_collision=[BOX], sim_from_canonical=None)
    kinds = {j.get("name"): j.get("type") for j in ET.parse(urdf).getroot().iter("joint")}
    assert kinds == {"panel_joint": "fixed"}  # no world link when sim_from_canonical is None
    assert mujoco.MjModel.from_xml_path(str(mjcf)).njnt == 0
    c = pybullet.connect(pybullet.DIRECT)
    try:
        body = pybullet.loadURDF(str(urdf), useFixedBase=True, physicsClientId=c)
        assert pybullet.getJointInfo(body, 0, physicsClientId=c)[2] == pybullet.JOINT_FIXED
    finally:
        pybullet.disconnect(c)
