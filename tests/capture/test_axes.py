"""Axis conventions: files written by hand in each format's own camera convention, read back,
and depth back-projected through the reader's poses and intrinsics must land on the known plane.

The files are built without the package's writers or its OpenGL/OpenCV conversion: cameras come
from a look-at construction in the format's own axes (OpenGL: x right, y up, looking down -z;
OpenCV: x right, y down, looking down +z), rotations are converted to quaternions with scipy, and
depth is ray-cast with the physical fact that image rows grow downwards. Depth and RGB share one
resolution here, so the result does not depend on how intrinsics are rescaled. K is off-centre
with fx != fy so a swapped or ignored principal point or focal length is caught.
"""

from __future__ import annotations

import json
import zipfile

import cv2
import lzfse
import numpy as np
import OpenEXR
import pytest
from scipy.spatial.transform import Rotation

from artitwin_core.capture import read_capture

W, H = 40, 30
FX, FY, CX, CY = 35.0, 37.0, 22.3, 13.1
NORMAL = np.array([0.2, -0.3, 1.0]) / np.linalg.norm([0.2, -0.3, 1.0])
OFFSET = 2.0  # plane: NORMAL . x = OFFSET (metres)


def look_at(rng):
    """Camera centre in front of the plane and unit forward/up-ish vectors in world coordinates."""
    centre = rng.uniform(-0.5, 0.5, 3) + NORMAL * (OFFSET - rng.uniform(1.0, 3.0))
    forward = NORMAL + rng.uniform(-0.3, 0.3, 3)
    forward /= np.linalg.norm(forward)
    up = rng.normal(size=3)
    right = np.cross(forward, up)
    right /= np.linalg.norm(right)
    return centre, forward, right, np.cross(right, forward)  # last: true up, orthogonal


def ground_truth(rng, n_frames=4):
    """Per frame: OpenGL and OpenCV camera-to-world rotations, centre, depth [H, W], points [H, W, 3]."""
    v, u = np.mgrid[0:H, 0:W].astype(np.float64)
    out = []
    for _ in range(n_frames):
        c, f, r, up = look_at(rng)
        rot_gl = np.stack([r, up, -f], 1)  # columns: camera x, y (up), z (backwards) in world
        rot_cv = np.stack([r, -up, f], 1)  # columns: camera x, y (down), z (forwards)
        assert np.isclose(np.linalg.det(rot_gl), 1) and np.isclose(np.linalg.det(rot_cv), 1)
        # A pixel (u, v) looks along right * (u - cx)/fx - up * (v - cy)/fy + forward (rows go down).
        dirs = r * ((u - CX) / FX)[..., None] - up * ((v - CY) / FY)[..., None] + f
        s = (OFFSET - NORMAL @ c) / (dirs @ NORMAL)  # depth along the optical axis (forward . dir = 1)
        assert np.all(s > 0.3)
        out.append(dict(rot_gl=rot_gl, rot_cv=rot_cv, centre=c, depth=s.astype(np.float32),
                        points=c + s[..., None] * dirs))
    return out


def pose7(rot, t):
    qx, qy, qz, qw = Rotation.from_matrix(rot).as_quat()
    return [qx, qy, qz, qw, *t]


def record3d_meta(frames):
    return {"w": W, "h": H, "dw": W, "dh": H, "fps": 30, "cameraType": 1,
            "K": [FX, 0, 0, 0, FY, 0, CX, CY, 1], "poses": [pose7(f["rot_gl"], f["centre"]) for f in frames]}


def jpg(img=None):
    return cv2.imencode(".jpg", np.full((H, W, 3), 128, np.uint8) if img is None else img)[1].tobytes()


def make_r3d(tmp_path, frames):
    p = tmp_path / "plane.r3d"
    with zipfile.ZipFile(p, "w") as zf:
        zf.writestr("metadata", json.dumps(record3d_meta(frames)))
        for i, f in enumerate(frames):
            zf.writestr(f"rgbd/{i}.jpg", jpg())
            zf.writestr(f"rgbd/{i}.depth", lzfse.compress(f["depth"].astype("<f4").tobytes()))
    return p, 1e-5  # float32 depth


def make_exr(tmp_path, frames):
    root = tmp_path / "EXR_RGBD"
    (root / "rgb").mkdir(parents=True)
    (root / "depth").mkdir()
    (root / "metadata.json").write_text(json.dumps(record3d_meta(frames)))
    for i, f in enumerate(frames):
        (root / "rgb" / f"{i}.jpg").write_bytes(jpg())
        OpenEXR.File({"compression": OpenEXR.ZIP_COMPRESSION, "type": OpenEXR.scanlineimage},
                     {"R": f["depth"].astype(np.float16)}).write(str(root / "depth" / f"{i}.exr"))
    # float16 keeps 11 bits: <= 2.5 mm at 5 m depth, times the ray length (<= 1.6) -> 4 mm; bound 6 mm.
    return root, 6e-3


def make_nerfstudio(tmp_path, frames):
    root = tmp_path / "ns"
    (root / "img").mkdir(parents=True)
    entries = []
    for i, f in enumerate(frames):
        (root / "img" / f"{i:04d}.jpg").write_bytes(jpg())
        cv2.imwrite(str(root / "img" / f"d{i:04d}.png"), np.round(f["depth"] * 1000).astype(np.uint16))
        m = np.eye(4)
        m[:3, :3], m[:3, 3] = f["rot_gl"], f["centre"]
        entries.append({"file_path": f"img/{i:04d}.jpg", "depth_file_path": f"img/d{i:04d}.png",
                        "transform_matrix": m.tolist()})
    (root / "transforms.json").write_text(json.dumps(
        {"fl_x": FX, "fl_y": FY, "cx": CX, "cy": CY, "w": W, "h": H, "camera_model": "PINHOLE", "frames": entries}))
    return root, 2e-3  # mm quantisation: 0.5 mm along z, times the ray length (<= 1.6); bound 2 mm


def make_stray(tmp_path, frames):
    root = tmp_path / "stray"
    (root / "depth").mkdir(parents=True)
    np.savetxt(root / "camera_matrix.csv", [[FX, 0, CX], [0, FY, CY], [0, 0, 1]], delimiter=",")
    rows = ["timestamp, frame, x, y, z, qx, qy, qz, qw"]
    vw = cv2.VideoWriter(str(root / "rgb.mp4"), cv2.VideoWriter_fourcc(*"FFV1"), 60, (W, H))
    for i, f in enumerate(frames):
        qx, qy, qz, qw = Rotation.from_matrix(f["rot_cv"]).as_quat()
        rows.append(", ".join(map(str, [i / 60, i, *f["centre"], qx, qy, qz, qw])))
        cv2.imwrite(str(root / "depth" / f"{i:06d}.png"), np.round(f["depth"] * 1000).astype(np.uint16))
        vw.write(np.full((H, W, 3), 128, np.uint8))
    vw.release()
    (root / "odometry.csv").write_text("\n".join(rows) + "\n")
    return root, 2e-3


@pytest.mark.parametrize("make", [make_r3d, make_exr, make_nerfstudio, make_stray])
def test_back_projected_depth_lands_on_the_plane(make, tmp_path):
    frames = ground_truth(np.random.default_rng(7))
    path, tol = make(tmp_path, frames)
    cap = read_capture(path)
    v, u = np.mgrid[0:H, 0:W].astype(np.float64)
    for t, f in enumerate(frames):
        fx, fy, cx, cy = cap.depth_intrinsics[t]
        z = cap.depth[t].astype(np.float64)
        cam = np.stack([(u - cx) / fx * z, (v - cy) / fy * z, z], -1)  # OpenCV axes
        world = cam @ cap.world_from_camera[t, :3, :3].T + cap.world_from_camera[t, :3, 3]
        assert np.max(np.abs(world @ NORMAL - OFFSET)) < tol  # on the plane
        assert np.max(np.linalg.norm(world - f["points"], axis=-1)) < tol  # at the right place on it
