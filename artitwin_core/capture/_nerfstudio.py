"""nerfstudio ``transforms.json`` datasets with depth.

Intrinsics ``fl_x, fl_y, cx, cy, w, h`` and ``camera_model`` (+ ``k1 k2 p1 p2 [k3]``) sit at the top
level or per frame. Each frame has ``file_path``, ``depth_file_path`` and ``transform_matrix``
(camera-to-world, OpenGL camera axes). Depth PNGs are uint16 times ``depth_unit_scale_factor``
(default 0.001: millimetres). Paths are relative to the folder holding ``transforms.json`` and
must stay inside it.
"""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np

from artitwin_core.capture._common import (
    ByteBudget,
    PoseStream,
    assemble,
    check_capture_for_writing,
    check_capture_size,
    check_depth_intrinsics_derivable,
    check_pose,
    check_side,
    clean_depth,
    decode_png_depth,
    decode_rgb,
    depth_intrinsics_from_rgb,
    encode_jpeg,
    encode_png,
    fit_rgb,
    frame_number,
    input_error,
    pose_stream,
    read_file_bytes,
)
from artitwin_core.capture._options import ReadOptions
from artitwin_core.capture._types import Capture
from artitwin_core.geometry import OPENGL_FROM_OPENCV

FORMAT = "nerfstudio"
# Perspective models whose parameters map onto OpenCV's k1 k2 p1 p2 k3. Fisheye, equirectangular
# and the 6-2-4 model need other projection code, which nothing downstream has.
SUPPORTED_CAMERA_MODELS = ("OPENCV", "PINHOLE", "SIMPLE_PINHOLE")
_INTR_KEYS = ("fl_x", "fl_y", "cx", "cy", "w", "h", "camera_model", "k1", "k2", "k3", "k4", "p1", "p2")
_FIX = "Fix transforms.json (see nerfstudio's data conventions) or re-export the dataset."


def transforms_path(path: str | Path) -> Path:
    """The ``transforms.json`` of a dataset given as its folder or the file itself."""
    p = Path(path)
    return p if p.is_file() else p / "transforms.json"


def _load(path: Path, budget: ByteBudget) -> dict:
    try:
        data = json.loads(read_file_bytes(path, budget))
    except (UnicodeDecodeError, json.JSONDecodeError) as exc:
        raise input_error(path, f"not valid JSON ({exc})", _FIX) from exc
    if not isinstance(data, dict) or not isinstance(data.get("frames"), list) or not data["frames"]:
        raise input_error(path, "expected a JSON object with a non-empty 'frames' list", _FIX)
    return data


def _inside(root: Path, rel: object, source: Path, frame: int, key: str) -> Path:
    if not isinstance(rel, str) or not rel:
        raise input_error(source, f"frame entry has no {key!r}", _FIX, frame)
    p = (root / rel).resolve()
    if not p.is_relative_to(root.resolve()):
        raise input_error(source, f"{key} {rel!r} points outside the dataset folder {root}",
                          "Copy the files into the dataset folder and use relative paths.", frame)
    return p


def _frame_table(path: Path, data: dict) -> list[tuple[int, dict]]:
    """``(frame number, entry)`` sorted by number; numbers from file names, else list positions."""
    frames = data["frames"]
    for k, f in enumerate(frames):
        if not isinstance(f, dict):
            raise input_error(path, f"frames[{k}] is not an object", _FIX, k)
    nums = [frame_number(str(f.get("file_path", ""))) for f in frames]
    if any(n is None for n in nums) or len(set(nums)) != len(nums):
        nums = list(range(len(frames)))
    return sorted(zip(nums, frames, strict=True), key=lambda x: x[0])


def _camera(path: Path, data: dict, entry: dict, frame: int) -> tuple[np.ndarray, tuple[int, int], np.ndarray | None]:
    """``(fx, fy, cx, cy)``, ``(w, h)`` and distortion for one frame (frame keys override)."""
    c = {k: entry.get(k, data.get(k)) for k in _INTR_KEYS}
    model = c["camera_model"] or "OPENCV"
    if model not in SUPPORTED_CAMERA_MODELS:
        raise input_error(path, f"camera_model {model!r} is not supported (supported: "
                          f"{', '.join(SUPPORTED_CAMERA_MODELS)})",
                          "Undistort the images to a pinhole or OPENCV model first (e.g. ns-process-data).", frame)
    if c["fl_y"] is None and model == "SIMPLE_PINHOLE":
        c["fl_y"] = c["fl_x"]
    for k in ("fl_x", "fl_y", "cx", "cy", "w", "h"):
        v = c[k]
        if isinstance(v, bool) or not isinstance(v, int | float) or not np.isfinite(v):
            raise input_error(path, f"intrinsic {k!r} is {v!r}, expected a number", _FIX, frame)
    if c["fl_x"] <= 0 or c["fl_y"] <= 0:
        raise input_error(path, f"focal lengths ({c['fl_x']}, {c['fl_y']}) must be positive", _FIX, frame)
    wh = (check_side(path, "w", c["w"]), check_side(path, "h", c["h"]))
    dist = None
    if model == "OPENCV":
        if c["k4"] not in (None, 0, 0.0):
            raise input_error(path, "k4 is set but the OPENCV model has no k4",
                              "Use camera_model OPENCV with k1 k2 p1 p2 [k3] only.", frame)
        keys = ["k1", "k2", "p1", "p2"] + (["k3"] if c["k3"] is not None else [])
        vals = [c[k] or 0.0 for k in keys]
        if not all(isinstance(v, int | float) and np.isfinite(v) for v in vals):
            raise input_error(path, f"distortion coefficients {vals} are not finite numbers", _FIX, frame)
        if any(vals):
            dist = np.array(vals, dtype=np.float64)
    return np.array([c["fl_x"], c["fl_y"], c["cx"], c["cy"]], dtype=np.float64), wh, dist


def nerfstudio_files(path: str | Path) -> list[Path]:
    """``transforms.json`` and every image and depth file it names."""
    tp = transforms_path(path)
    data = _load(tp, ByteBudget(ReadOptions()))
    out = [tp]
    for k, (_, f) in enumerate(_frame_table(tp, data)):
        out.append(_inside(tp.parent, f.get("file_path"), tp, k, "file_path"))
        if f.get("depth_file_path"):
            out.append(_inside(tp.parent, f.get("depth_file_path"), tp, k, "depth_file_path"))
    return out


def read_nerfstudio(path: str | Path, options: ReadOptions | None = None) -> Capture:
    """Read a nerfstudio dataset (folder or ``transforms.json``) with depth into a :class:`Capture`.

    Timestamps come from a per-frame ``timestamp`` (seconds) when every frame has one (ArtiTwin's
    writer adds it; nerfstudio ignores it), else from frame numbers at the top-level ``fps``
    (default 30).
    """
    tp = transforms_path(path)
    options = options or ReadOptions()
    budget = ByteBudget(options)
    data = _load(tp, budget)
    root = tp.parent
    table = _frame_table(tp, data)
    scale = data.get("depth_unit_scale_factor", 1e-3)
    if isinstance(scale, bool) or not isinstance(scale, int | float) or not 0 < scale < 1e3:
        raise input_error(tp, f"depth_unit_scale_factor is {scale!r}, expected a positive number (0.001 = mm)", _FIX)
    fps = data.get("fps", 30.0)
    if isinstance(fps, bool) or not isinstance(fps, int | float) or not 0 < fps < 10000:
        raise input_error(tp, f"fps is {fps!r}, expected a positive frame rate", _FIX)
    use_stamps = all(isinstance(f.get("timestamp"), int | float) for _, f in table)

    picked = [table[p] for p in options.select(len(table))]
    intr0, wh0, dist0 = _camera(tp, data, picked[0][1], picked[0][0])
    rgb, depth, poses, intr, stamps, depth_wh = [], [], [], [], [], None
    for num, f in picked:
        k, wh, dist = _camera(tp, data, f, num)
        if wh != wh0:
            raise input_error(tp, f"image size {wh} differs from the first frame's {wh0}",
                              "All frames of one recording must share a size.", num)
        if (dist is None) != (dist0 is None) or (dist is not None and not np.array_equal(dist, dist0)):
            raise input_error(tp, "distortion coefficients differ from the first frame's",
                              "ArtiTwin handles one camera per recording; undistort the images first.", num)
        img_path = _inside(root, f.get("file_path"), tp, num, "file_path")
        if not f.get("depth_file_path"):
            raise input_error(tp, "frame entry has no 'depth_file_path'",
                              "ArtiTwin needs depth for every frame; export the dataset with depth.", num)
        d_path = _inside(root, f.get("depth_file_path"), tp, num, "depth_file_path")
        m = np.asarray(f.get("transform_matrix"), dtype=np.float64) if f.get("transform_matrix") is not None else None
        if m is None or m.shape not in ((4, 4), (3, 4)):
            raise input_error(tp, f"transform_matrix is missing or not 4x4 (got {None if m is None else m.shape})",
                              _FIX, num)
        if m.shape == (3, 4):
            m = np.vstack([m, [0, 0, 0, 1]])
        pose = m @ OPENGL_FROM_OPENCV
        check_pose(pose, tp, num)
        if depth_wh is None:
            check_capture_size(root, len(picked), wh0, (wh0[0], wh0[1]), options)
        if not options.skip_rgb:
            rgb.append(fit_rgb(decode_rgb(read_file_bytes(img_path, budget, num), img_path, num, wh0, budget), options))
        raw = decode_png_depth(read_file_bytes(d_path, budget, num), d_path, num, depth_wh, budget)
        depth_wh = (raw.shape[1], raw.shape[0])
        depth.append(clean_depth(raw.astype(np.float32) * np.float32(scale), d_path, num, options))
        poses.append(pose)
        intr.append(k)
        stamps.append(float(f["timestamp"]) if use_stamps else num / fps)
    rgb_intr = np.array(intr)
    return assemble(
        rgb=rgb, depth=depth, confidence=None, rgb_intrinsics=rgb_intr,
        depth_intrinsics=depth_intrinsics_from_rgb(rgb_intr, wh0, depth_wh),
        world_from_camera=np.array(poses), timestamps=np.array(stamps), frame_ids=[n for n, _ in picked],
        distortion=dist0, source_format=FORMAT, options=options, rgb_source_wh=wh0,
        stream=_pose_stream(table, use_stamps, fps) if len(picked) < len(table) else None,
    )


def _pose_stream(table: list, use_stamps: bool, fps: float) -> PoseStream:
    """Every listed frame's pose (a frame read or not; one that is not a pose is left out)."""
    poses = []
    for _, f in table:
        try:
            m = np.asarray(f.get("transform_matrix"), dtype=np.float64)
            m = np.vstack([m, [0, 0, 0, 1]]) if m.shape == (3, 4) else m
            poses.append(m @ OPENGL_FROM_OPENCV if m.shape == (4, 4) else None)
        except (TypeError, ValueError):
            poses.append(None)
    stamps = [float(f["timestamp"]) if use_stamps else num / fps for num, f in table]
    return pose_stream([num for num, _ in table], stamps, poses, [True] * len(table))


def depth_to_mm_png(depth_m: np.ndarray) -> np.ndarray:
    """``[h, w]`` metres (NaN = none) to uint16 millimetres (0 = none); refuses depth >= 65.535 m."""
    d = np.where(np.isfinite(depth_m) & (depth_m > 0), depth_m, 0.0)
    if np.max(d, initial=0.0) >= 65.5345:
        raise ValueError("depth of 65.535 m or more does not fit uint16 millimetres")
    return np.round(d * 1000.0).astype(np.uint16)


def write_nerfstudio(capture: Capture, folder: str | Path) -> Path:
    """Write ``capture`` as a nerfstudio dataset in ``folder``; returns the ``transforms.json`` path.

    ``images/frame_<n>.jpg`` (quality 95), ``depth/frame_<n>.png`` (uint16 mm, so depth is
    quantised to 0.5 mm), OpenGL ``transform_matrix``; intrinsics at the top level when every
    frame shares them, else per frame; each frame also gets ``timestamp`` (seconds). Confidence
    maps are not part of the format and are dropped.
    """
    check_capture_for_writing(capture)
    check_depth_intrinsics_derivable(capture, FORMAT)
    root = Path(folder)
    (root / "images").mkdir(parents=True, exist_ok=True)
    (root / "depth").mkdir(parents=True, exist_ok=True)
    w, h = capture.rgb_size
    intr = capture.rgb_intrinsics
    shared = bool(np.all(intr == intr[0]))
    data: dict = {"w": w, "h": h, "camera_model": "OPENCV", "depth_unit_scale_factor": 0.001}
    if capture.distortion is not None:
        dist = [float(x) for x in capture.distortion]
        if len(dist) not in (4, 5):
            raise ValueError("nerfstudio's OPENCV model takes 4 or 5 coefficients (k1 k2 p1 p2 [k3])")
        data.update(dict(zip(["k1", "k2", "p1", "p2", "k3"], dist, strict=False)))
    if shared:
        data.update(fl_x=float(intr[0, 0]), fl_y=float(intr[0, 1]), cx=float(intr[0, 2]), cy=float(intr[0, 3]))
    frames = []
    world_from_gl = capture.world_from_camera @ OPENGL_FROM_OPENCV
    for t, i in enumerate(capture.frame_ids.tolist()):
        name = f"frame_{i:05d}"
        (root / "images" / f"{name}.jpg").write_bytes(encode_jpeg(capture.rgb[t]))
        (root / "depth" / f"{name}.png").write_bytes(encode_png(depth_to_mm_png(capture.depth[t])))
        entry = {"file_path": f"images/{name}.jpg", "depth_file_path": f"depth/{name}.png",
                 "transform_matrix": world_from_gl[t].tolist(), "timestamp": float(capture.timestamps[t])}
        if not shared:
            entry.update(fl_x=float(intr[t, 0]), fl_y=float(intr[t, 1]), cx=float(intr[t, 2]), cy=float(intr[t, 3]))
        frames.append(entry)
    data["frames"] = frames
    out = root / "transforms.json"
    out.write_text(json.dumps(data, indent=2))
    return out
