"""The viewer's scene on a live viser server: what it holds, where sliders put the parts, what a client receives.

The server side is read through viser's own handles; ``test_a_client_receives_the_twin_and_drives_it``
speaks viser's websocket protocol as the browser does (no rendering), so the messages the page
gets are checked too. Rendering in a real browser is ``test_viewer_browser.py``.
"""

from __future__ import annotations

import json
import time

import numpy as np
import pytest

from artitwin._viewer import build_viewer, view
from artitwin_core._errors import InputError
from artitwin_core.gaussians import LABEL_PART, GaussianParams
from artitwin_core.joints import Joint
from artitwin_core.reconstruction import write_ply
from artitwin_core.viewer import MeshPiece, TwinData, heat_colors, quat_wxyz_to_matrix, splat_arrays
from tests.viewer.conftest import free_port


def _pose(frame) -> np.ndarray:
    out = np.eye(4)
    out[:3, :3] = quat_wxyz_to_matrix(np.asarray(frame.wxyz)[None])[0]
    out[:3, 3] = frame.position
    return out


def _closed_form(joint_type: str, axis, pivot, q: float, pitch: float = 0.0) -> np.ndarray:
    # Written out here rather than taken from artitwin_core.joints: Rodrigues about the axis line
    # through the pivot, plus pitch * q along it (screw), or q along it (prismatic).
    a = np.asarray(axis, np.float64) / np.linalg.norm(axis)
    p = np.asarray(pivot, np.float64)
    out = np.eye(4)
    if joint_type == "prismatic":
        out[:3, 3] = q * a
        return out
    k = np.array([[0, -a[2], a[1]], [a[2], 0, -a[0]], [-a[1], a[0], 0]])
    rot = np.eye(3) + np.sin(q) * k + (1 - np.cos(q)) * k @ k
    out[:3, :3] = rot
    out[:3, 3] = p - rot @ p + (pitch * q * a if joint_type == "screw" else 0.0)
    return out


def _three_joint_twin(n: int = 900, with_extras: bool = False) -> TwinData:
    rng = np.random.default_rng(3)
    labels = rng.integers(0, LABEL_PART + 3, n).astype(np.int32)
    params = GaussianParams(
        means=rng.uniform(-1, 1, (n, 3)).astype(np.float32),
        quats_wxyz=rng.normal(size=(n, 4)).astype(np.float32),
        log_scales=rng.uniform(-5, -3, (n, 3)).astype(np.float32),
        opacity_logits=rng.normal(size=n).astype(np.float32),
        sh=rng.normal(size=(n, 1, 3)).astype(np.float32),
        labels=labels,
    )

    def joint(kind, axis, pivot, q_range, pitch=0.0):
        return Joint(kind, np.asarray(axis, float) / np.linalg.norm(axis), np.asarray(pivot, float), np.zeros(1),
                     np.asarray(q_range, float), np.zeros(1), np.ones(1), pitch)

    joints = (joint("revolute", [0.1, 1, 0.2], [0.4, 0.1, -0.3], [-0.3, 1.4]),
              joint("prismatic", [0, 0.2, 1], [0.0, 0.5, 0.0], [0.0, 0.35]),
              joint("screw", [1, 0, 0.3], [-0.2, 0.3, 0.1], [0.0, 6.0], pitch=0.004))
    extras = {}
    if with_extras:
        box = np.array([[0, 0, 0], [1, 0, 0], [0, 1, 0], [0, 0, 1]], np.float32) * 0.1
        tris = np.array([[0, 1, 2], [0, 1, 3], [0, 2, 3], [1, 2, 3]], np.int32)
        extras = dict(residual=np.linspace(0, 1, n).astype(np.float32),
                      collision=(MeshPiece("base_collision_00", box, tris, -1), MeshPiece("door_collision_00", box, tris, 0)))
    return TwinData(params, joints, ("door", "drawer", "lid"), **extras)


@pytest.fixture
def viewer3():
    v = build_viewer(_three_joint_twin(with_extras=True), port=free_port())
    yield v
    v.close()


def test_sliders_put_the_door_where_the_ground_truth_has_it(door_scene, door_twin):
    # The slider at the true q(t) must pose the part node at the scene's true part motion.
    truth = door_scene.truth
    v = build_viewer(door_twin, port=free_port())
    try:
        (slider,) = v.sliders
        (frame,) = v.part_frames
        for t in np.linspace(0, truth.joints[0].q.shape[0] - 1, 7).round().astype(int):
            slider.value = float(truth.joints[0].q[t])  # a server-side set runs the same callback as a drag
            np.testing.assert_allclose(_pose(frame), truth.part_world_from_closed[0, t], atol=1e-9)
    finally:
        v.close()


def test_sliders_for_revolute_prismatic_and_screw_joints(viewer3):
    twin = viewer3.twin
    rng = np.random.default_rng(0)
    for _ in range(5):
        q = [rng.uniform(s.min, s.max) for s in viewer3.sliders]
        for s, qk in zip(viewer3.sliders, q, strict=True):
            s.value = float(qk)
        for frame, j, qk in zip(viewer3.part_frames, twin.joints, q, strict=True):
            # Quaternion round trip in float64: 1e-12 measured, 1e-9 asked.
            np.testing.assert_allclose(_pose(frame), _closed_form(j.joint_type, j.axis, j.pivot, qk, j.pitch),
                                       atol=1e-9)


def test_scene_holds_the_twin_axes_sliders_and_toggles(viewer3):
    twin = viewer3.twin
    labels = twin.gaussians.labels
    centers, _, rgbs, _ = splat_arrays(twin.gaussians)
    # One splat object for the fixed Gaussians and one per part, under the part's node; every Gaussian once.
    assert sorted(viewer3.splats) == ["/twin/part_0/splats", "/twin/part_1/splats", "/twin/part_2/splats",
                                      "/twin/static"]
    counts = {name: h.buffer.shape[0] for name, (h, _, _) in viewer3.splats.items()}
    assert sum(counts.values()) == twin.gaussians.num_gaussians
    for k in range(3):
        handle = viewer3.splats[f"/twin/part_{k}/splats"][0]
        # Centres are stored in the part frame at the closed state (float32 bits in the first 3 words).
        np.testing.assert_array_equal(handle.buffer[:, :3].view(np.float32), centers[labels == LABEL_PART + k])
    # Slider ranges are the estimated q ranges (each already includes 0 here).
    for s, j in zip(viewer3.sliders, twin.joints, strict=True):
        assert (s.min, s.max) == tuple(float(v) for v in j.q_range)
    assert [s.label for s in viewer3.sliders] == ["door (rad)", "drawer (m)", "lid (rad)"]
    # Each axis is drawn as a segment along the joint axis through the pivot.
    scene = viewer3.server.scene
    for k, j in enumerate(twin.joints):
        seg = scene._handle_from_node_name[f"/axes/{k}"].points[0].astype(np.float64)
        d = seg[1] - seg[0]
        np.testing.assert_allclose(d / np.linalg.norm(d), j.axis, atol=1e-6)
        np.testing.assert_allclose(seg.mean(0), j.pivot, atol=1e-6)
    # Collision meshes: hidden until toggled, the part's piece under the part node so it moves with it.
    pieces = {name: scene._handle_from_node_name[name] for name in ("/collision/base_collision_00",
                                                                   "/twin/part_0/collision/door_collision_00")}
    assert not any(h.visible for h in pieces.values())
    viewer3.toggles["collision"].value = True
    assert all(h.visible for h in pieces.values())
    # Residual heat map: the splat colours switch to the heat colours and back.
    part0, base_rgb, _ = viewer3.splats["/twin/part_0/splats"]
    heat = heat_colors(twin.residual)[labels == LABEL_PART]
    viewer3.toggles["residual"].value = True
    np.testing.assert_allclose(part0.rgbs / 255.0, heat, atol=1 / 255)  # viser keeps colours as uint8
    viewer3.toggles["residual"].value = False
    np.testing.assert_allclose(part0.rgbs / 255.0, rgbs[labels == LABEL_PART], atol=1 / 255)
    np.testing.assert_allclose(base_rgb, rgbs[labels == LABEL_PART])
    # No cameras were given: the toggle says so rather than showing nothing.
    assert viewer3.toggles["cameras"].disabled


def test_camera_frustums_sit_at_the_capture_poses(door_twin):
    v = build_viewer(door_twin, port=free_port())
    try:
        cams = door_twin.cameras
        frustums = {n: h for n, h in v.server.scene._handle_from_node_name.items() if n.startswith("/cameras/")}
        step = int(np.ceil(cams.world_from_camera.shape[0] / 60))
        assert len(frustums) == len(range(0, cams.world_from_camera.shape[0], step))
        for name, h in frustums.items():
            i = int(name.rsplit("/", 1)[1])
            np.testing.assert_allclose(_pose(h), cams.world_from_camera[i], atol=1e-9)
    finally:
        v.close()


# --- a client on the wire -------------------------------------------------------------------------
class _WireClient:
    """The part of viser's browser protocol a test needs: decode server frames, send GUI updates."""

    def __init__(self, url: str):
        import viser
        from websockets.sync.client import connect

        self.ws = connect(url.replace("http", "ws"), subprotocols=[f"viser-v{viser.__version__}"], max_size=None)
        self.buffer_lengths: list[int] = []

    def receive(self, until, timeout_s: float = 10.0) -> list[dict]:
        """Messages received until ``until(messages)`` holds (or the timeout)."""
        import msgspec
        import zstandard

        out: list[dict] = []
        end = time.monotonic() + timeout_s
        while time.monotonic() < end and not until(out):
            try:
                raw = self.ws.recv(timeout=0.2)
            except TimeoutError:
                continue
            size, compressed = int.from_bytes(raw[:8], "little"), int.from_bytes(raw[8:16], "little")
            frame = msgspec.msgpack.decode(
                zstandard.ZstdDecompressor().decompress(raw[16 : 16 + compressed], max_output_size=size))
            base = len(self.buffer_lengths)
            self.buffer_lengths.extend(frame["binaryBufferLengths"])
            for m in frame["messages"]:
                m["_buffer_base"] = base
            out.extend(frame["messages"])
        return out

    def send(self, message: dict) -> None:
        import msgspec

        self.ws.send(msgspec.msgpack.encode(message))

    def close(self) -> None:
        self.ws.close()


def test_a_client_receives_the_twin_and_drives_it(viewer3):
    twin = viewer3.twin
    client = _WireClient(viewer3.url)
    try:
        init = client.receive(lambda ms: any(m["type"] == "ReplayDoneMessage" for m in ms))
        splats = {m["name"]: m for m in init if m["type"] == "GaussianSplatsMessage"}
        assert set(splats) == set(viewer3.splats)
        nbytes = [client.buffer_lengths[m["_buffer_base"] + m["props"]["buffer"]["__binary_index"]]
                  for m in splats.values()]
        assert sum(nbytes) == 32 * twin.gaussians.num_gaussians  # 8 uint32 words per Gaussian
        sliders = [m for m in init if m["type"] == "GuiSliderMessage"]
        assert [(m["props"]["min"], m["props"]["max"]) for m in sliders] == [tuple(j.q_range) for j in twin.joints]

        # A browser counts as connected once it reports its camera; then it drags the drawer slider.
        client.send({"type": "ViewerCameraMessage", "wxyz": [1.0, 0, 0, 0], "position": [0.0, 0, 3], "fov": 1.0,
                     "near": 0.01, "far": 100.0, "image_height": 480, "image_width": 640, "look_at": [0.0, 0, 0],
                     "up_direction": [0.0, 1, 0]})
        time.sleep(0.2)
        client.send({"type": "GuiUpdateMessage", "uuid": sliders[1]["uuid"], "updates": {"value": 0.2}})
        moved = client.receive(lambda ms: any(m["type"] == "SetPositionMessage" for m in ms))
        pos = [m for m in moved if m["type"] == "SetPositionMessage"]
        assert [m["name"] for m in pos] == ["/twin/part_1"]
        j = twin.joints[1]
        np.testing.assert_allclose(pos[0]["position"], _closed_form("prismatic", j.axis, j.pivot, 0.2)[:3, 3], atol=1e-9)
    finally:
        client.close()


# --- the command ----------------------------------------------------------------------------------
def test_view_serves_a_ply_with_its_joints_and_refuses_a_missing_path(tmp_path, door_twin):
    write_ply(tmp_path / "twin.ply", door_twin.gaussians)
    np.save(tmp_path / "labels.npy", door_twin.gaussians.labels)
    j, name = door_twin.joints[0], door_twin.joint_names[0]
    (tmp_path / "joints.json").write_text(json.dumps({"joints": [
        {"name": name, "type": j.joint_type, "axis": j.axis.tolist(), "pivot": j.pivot.tolist(),
         "range": j.q_range.tolist()}]}))
    (tmp_path / "export").mkdir()
    for f in ("twin.urdf", "twin.usda"):
        (tmp_path / "export" / f).write_text("")
    lines: list[str] = []
    v = view(tmp_path / "twin.ply", port=free_port(), joints=tmp_path / "joints.json", labels=tmp_path / "labels.npy",
             export_dir=tmp_path / "export", block=False, echo=lines.append)
    try:
        assert v.url in lines[-1]
        assert "twin.urdf, twin.usda" in lines[-2] and "Isaac Sim" in lines[-2]  # the USD stage is listed
        assert f"{door_twin.gaussians.num_gaussians} Gaussians, 1 joint(s)" in lines[0]
        assert sum(h.buffer.shape[0] for h, _, _ in v.splats.values()) == door_twin.gaussians.num_gaussians
        assert (v.sliders[0].min, v.sliders[0].max) == tuple(float(x) for x in j.q_range)
    finally:
        v.close()
    with pytest.raises(InputError, match="nothing.ply"):
        view(tmp_path / "nothing.ply", block=False)
    with pytest.raises(InputError, match="no summary.json"):
        view(tmp_path, block=False)
