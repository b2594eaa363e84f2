"""Stray Scanner recordings: ``rgb.mp4``, ``depth/<frame:06d>.png`` (uint16 mm) or ``.npy`` (older
app versions), optional ``confidence/<frame:06d>.png`` (0/1/2), ``camera_matrix.csv`` (3x3 K at the
video's resolution) and ``odometry.csv`` (``timestamp, frame, x, y, z, qx, qy, qz, qw``; older
versions lack ``timestamp`` and ``frame``, rows then follow the video frames).

Poses are read as camera-to-world in OpenCV camera axes, as the public Stray readers do (not yet
verified on a real capture).
"""

from __future__ import annotations

import math
from pathlib import Path

import cv2
import numpy as np

from artitwin_core.capture._common import (
    ByteBudget,
    PoseStream,
    assemble,
    check_capture_for_writing,
    check_capture_size,
    check_depth_intrinsics_derivable,
    check_pose,
    clean_depth,
    decode_png_depth,
    depth_intrinsics_from_rgb,
    encode_png,
    fit_rgb,
    input_error,
    pose_stream,
    read_file_bytes,
)
from artitwin_core.capture._nerfstudio import depth_to_mm_png
from artitwin_core.capture._options import MAX_SIDE_PIXELS, ReadOptions
from artitwin_core.capture._types import Capture
from artitwin_core.geometry import make_se3, matrix_to_quat_wxyz, quat_wxyz_to_matrix

FORMAT = "stray"
_NEW_COLUMNS = ["timestamp", "frame", "x", "y", "z", "qx", "qy", "qz", "qw"]
_OLD_COLUMNS = ["x", "y", "z", "qx", "qy", "qz", "qw"]
_FIX = "Export the recording from Stray Scanner again and copy the whole folder."


def _read_k(path: Path, budget: ByteBudget) -> np.ndarray:
    text = read_file_bytes(path, budget).decode("utf-8", errors="replace")
    try:
        k = np.array([[float(v) for v in line.split(",")] for line in text.splitlines() if line.strip()])
    except ValueError as exc:
        raise input_error(path, f"not a 3x3 table of numbers ({exc})", _FIX) from exc
    if k.shape != (3, 3) or not np.all(np.isfinite(k)):
        raise input_error(path, f"expected 3 rows of 3 numbers (K), got shape {k.shape}", _FIX)
    if k[0, 0] <= 0 or k[1, 1] <= 0 or abs(k[2, 2] - 1) > 1e-6 or np.any(np.abs(k[2, :2]) > 1e-6):
        raise input_error(path, f"{k.tolist()} is not a pinhole matrix [[fx,0,cx],[0,fy,cy],[0,0,1]]", _FIX)
    return np.array([k[0, 0], k[1, 1], k[0, 2], k[1, 2]])


def _read_odometry(path: Path, budget: ByteBudget) -> tuple[np.ndarray, bool]:
    """``([N, 9] timestamp, frame, x, y, z, qx, qy, qz, qw, has_timestamps)``; old files get
    ``frame`` = row number and NaN timestamps."""
    lines = [ln for ln in read_file_bytes(path, budget).decode("utf-8", errors="replace").splitlines() if ln.strip()]
    if not lines:
        raise input_error(path, "the file is empty", _FIX)
    first = [c.strip().lower() for c in lines[0].split(",")]
    has_header = any(c and not _is_number(c) for c in first)
    if has_header:
        cols, rows = first, lines[1:]
        if not (set(_NEW_COLUMNS) <= set(cols) or set(_OLD_COLUMNS) <= set(cols)):
            raise input_error(path, f"header {first} lacks the columns {_NEW_COLUMNS} (or {_OLD_COLUMNS})", _FIX)
    else:
        cols = _NEW_COLUMNS if len(first) == 9 else _OLD_COLUMNS if len(first) == 7 else None
        if cols is None:
            raise input_error(path, f"rows have {len(first)} columns and no header; expected 9 "
                              f"({', '.join(_NEW_COLUMNS)}) or 7", _FIX)
        rows = lines
    table = []
    for r, ln in enumerate(rows):
        vals = ln.split(",")
        if len(vals) != len(cols):
            raise input_error(path, f"row {r + 1} has {len(vals)} values, the header {len(cols)}", _FIX)
        try:
            table.append([float(v) for v in vals])
        except ValueError as exc:
            raise input_error(path, f"row {r + 1} holds a value that is not a number ({exc})", _FIX) from exc
    if not table:
        raise input_error(path, "the file has no pose rows", "The recording is empty; record again.")
    arr = np.array(table)
    idx = {c: k for k, c in enumerate(cols)}
    has_new = "timestamp" in idx and "frame" in idx
    out = np.empty((len(arr), 9))
    out[:, 0] = arr[:, idx["timestamp"]] if has_new else np.nan
    out[:, 1] = arr[:, idx["frame"]] if has_new else np.arange(len(arr))
    for k, c in enumerate(_OLD_COLUMNS):
        out[:, 2 + k] = arr[:, idx[c]]
    frames = out[:, 1]
    if np.any(frames != np.round(frames)) or np.any(frames < 0) or np.any(np.diff(frames) <= 0):
        raise input_error(path, "the 'frame' column must hold increasing non-negative integers", _FIX)
    return out, has_new


def _is_number(s: str) -> bool:
    try:
        float(s)
    except ValueError:
        return False
    return True


def _depth_file(root: Path, frame: int) -> Path | None:
    for suffix in (".png", ".npy"):
        p = root / "depth" / f"{frame:06d}{suffix}"
        if p.is_file():
            return p
    return None


def _read_npy_depth(path: Path, frame: int, expected_wh: tuple[int, int] | None, budget: ByteBudget) -> np.ndarray:
    """Older Stray depth: ``.npy`` uint16 millimetres (float arrays are taken as metres)."""
    try:
        with path.open("rb") as fh:
            version = np.lib.format.read_magic(fh)
            # Header only: the shape is checked against the limits before any allocation.
            read_header = (np.lib.format.read_array_header_1_0 if version == (1, 0)
                           else np.lib.format.read_array_header_2_0)
            shape, _, dtype = read_header(fh)
    except (OSError, ValueError) as exc:
        raise input_error(path, f"not a readable .npy array ({exc})", _FIX, frame) from exc
    if len(shape) != 2 or dtype.kind not in "uf":
        raise input_error(path, f"holds a {dtype} array of shape {shape}, expected [h, w] uint16 mm", _FIX, frame)
    if expected_wh is not None and (shape[1], shape[0]) != tuple(expected_wh):
        raise input_error(path, f"depth is {shape[1]}x{shape[0]}, expected {expected_wh[0]}x{expected_wh[1]}",
                          _FIX, frame)
    budget.take(int(np.prod(shape)) * dtype.itemsize, path, frame)
    arr = np.load(path, allow_pickle=False)
    return arr.astype(np.float32) * np.float32(1e-3) if dtype.kind == "u" else arr.astype(np.float32)


def stray_files(root: str | Path) -> list[Path]:
    """The files a Stray recording's frames are read from (video, CSVs, depth and confidence)."""
    root = Path(root)
    odo, _ = _read_odometry(root / "odometry.csv", ByteBudget(ReadOptions()))
    out = [root / "rgb.mp4", root / "camera_matrix.csv", root / "odometry.csv"]
    for f in odo[:, 1].astype(int):
        d = _depth_file(root, f)
        if d is not None:
            out.append(d)
        c = root / "confidence" / f"{f:06d}.png"
        if c.is_file():
            out.append(c)
    return out


def read_stray(folder: str | Path, options: ReadOptions | None = None) -> Capture:
    """Read a Stray Scanner recording folder into a :class:`Capture`.

    Odometry row with frame number ``f`` takes video frame ``f``, ``depth/<f>.png`` and
    ``confidence/<f>.png``. Without a timestamp column, timestamps are ``f / video fps``.
    """
    root = Path(folder)
    options = options or ReadOptions()
    budget = ByteBudget(options)
    k = _read_k(root / "camera_matrix.csv", budget)
    odo_path = root / "odometry.csv"
    odo, has_stamps = _read_odometry(odo_path, budget)
    video_path = root / "rgb.mp4"
    if not video_path.is_file():
        raise input_error(video_path, "the video is missing", _FIX)
    # The video is decoded frame by frame and each decoded frame is counted below; its file size
    # (hundreds of MB for a long HEVC recording) is not a decompression risk in itself.
    cap = cv2.VideoCapture(str(video_path))
    try:
        if not cap.isOpened():
            raise input_error(video_path, "the video cannot be opened (damaged, or a codec OpenCV lacks)",
                              "Re-export it, or transcode it to H.264/MPEG-4 with ffmpeg.")
        vw, vh = int(cap.get(cv2.CAP_PROP_FRAME_WIDTH)), int(cap.get(cv2.CAP_PROP_FRAME_HEIGHT))
        if not (1 <= vw <= MAX_SIDE_PIXELS and 1 <= vh <= MAX_SIDE_PIXELS):
            raise input_error(video_path, f"the video declares {vw}x{vh} pixels", _FIX)
        if not (0 <= k[2] <= vw and 0 <= k[3] <= vh):
            raise input_error(root / "camera_matrix.csv", f"the principal point ({k[2]:.1f}, {k[3]:.1f}) lies "
                              f"outside the {vw}x{vh} video", "K must be given at the video's resolution; "
                              "re-export the recording or rescale camera_matrix.csv.")
        fps = cap.get(cv2.CAP_PROP_FPS)
        fps = fps if math.isfinite(fps) and fps > 0 else 60.0

        frames = odo[:, 1].astype(np.int64)
        picked = [int(frames[p]) for p in options.select(len(frames))]
        rows = {int(f): r for r, f in enumerate(frames)}
        has_conf = (root / "confidence").is_dir()
        depth, conf, poses, stamps, depth_wh = [], [], [], [], None
        for f in picked:
            d_path = _depth_file(root, f)
            if d_path is None:
                raise input_error(root / "depth" / f"{f:06d}.png", "the depth frame is missing (odometry lists it)",
                                  _FIX, f)
            if d_path.suffix == ".png":
                raw = decode_png_depth(read_file_bytes(d_path, budget, f), d_path, f, depth_wh, budget)
                d = raw.astype(np.float32) * np.float32(1e-3)
            else:
                d = _read_npy_depth(d_path, f, depth_wh, budget)
            if depth_wh is None:
                depth_wh = (d.shape[1], d.shape[0])
                check_capture_size(root, len(picked), (vw, vh), depth_wh, options)
            depth.append(clean_depth(d, d_path, f, options))
            if has_conf:
                c_path = root / "confidence" / f"{f:06d}.png"
                conf.append(decode_png_depth(read_file_bytes(c_path, budget, f), c_path, f, depth_wh, budget,
                                             dtype=np.uint8))
            row = odo[rows[f]]
            x, y, z, qx, qy, qz, qw = row[2:]
            qn = math.sqrt(qx * qx + qy * qy + qz * qz + qw * qw)
            if not math.isfinite(qn) or abs(qn - 1) > 1e-2 or not np.all(np.isfinite(row[2:5])):
                raise input_error(odo_path, f"the pose is not rigid (quaternion norm {qn:.4g}, position "
                                  f"{[x, y, z]})", "The tracking data is damaged; remove the frame or re-record.", f)
            pose = make_se3(quat_wxyz_to_matrix(np.array([qw, qx, qy, qz])), np.array([x, y, z]))
            check_pose(pose, odo_path, f)
            poses.append(pose)
            stamps.append(row[0] - odo[0, 0] if has_stamps else f / fps)

        rgb, pos = [], 0
        for f in [] if options.skip_rgb else picked:
            while pos < f:
                if not cap.grab():
                    break
                pos += 1
            ok, bgr = cap.read() if pos == f else (False, None)
            if not ok:
                raise input_error(video_path, f"the video ends before frame {f} (odometry lists "
                                  f"{len(frames)} frames up to {int(frames[-1])}): frames and poses do not match",
                                  _FIX, f)
            pos += 1
            budget.take(bgr.nbytes, video_path, f)
            rgb.append(fit_rgb(cv2.cvtColor(bgr, cv2.COLOR_BGR2RGB), options))
    finally:
        cap.release()
    rgb_intr = np.tile(k, (len(picked), 1))
    return assemble(
        rgb=rgb, depth=depth, confidence=conf if has_conf else None, rgb_intrinsics=rgb_intr,
        depth_intrinsics=depth_intrinsics_from_rgb(rgb_intr, (vw, vh), depth_wh),
        world_from_camera=np.array(poses), timestamps=np.array(stamps), frame_ids=picked,
        distortion=None, source_format=FORMAT, options=options, rgb_source_wh=(vw, vh),
        stream=_pose_stream(odo, has_stamps, fps) if len(picked) < len(frames) else None,
    )


def _pose_stream(odo: np.ndarray, has_stamps: bool, fps: float) -> PoseStream:
    """Every odometry row's pose (a frame read or not; a row that is not a pose is left out)."""
    poses = []
    for row in odo:
        x, y, z, qx, qy, qz, qw = row[2:]
        qn = math.sqrt(qx * qx + qy * qy + qz * qz + qw * qw)
        ok = math.isfinite(qn) and abs(qn - 1) <= 1e-2 and bool(np.all(np.isfinite(row[2:5])))
        poses.append(make_se3(quat_wxyz_to_matrix(np.array([qw, qx, qy, qz])), np.array([x, y, z])) if ok else None)
    stamps = odo[:, 0] - odo[0, 0] if has_stamps else odo[:, 1] / fps
    return pose_stream(odo[:, 1].astype(np.int64), stamps, poses, [True] * len(odo))


def write_stray(capture: Capture, folder: str | Path, *, lossless: bool = False) -> Path:
    """Write ``capture`` as a Stray Scanner recording in ``folder``; returns the folder.

    The app writes HEVC, which OpenCV cannot encode; this writes MPEG-4 Part 2 (``mp4v``, lossy)
    or, with ``lossless=True``, FFV1 in the same ``rgb.mp4`` (OpenCV reads both). Video frames
    for gaps in ``frame_ids`` repeat the previous frame. Depth is uint16 mm (0.5 mm quantisation);
    confidence is written when present. Stray has one K: per-frame intrinsics must all be equal.
    """
    check_capture_for_writing(capture)
    check_depth_intrinsics_derivable(capture, FORMAT)
    if capture.distortion is not None and np.any(capture.distortion != 0):
        raise ValueError("Stray stores pinhole images; this capture has lens distortion")
    k = capture.rgb_intrinsics
    if np.max(np.abs(k - k[0])) > 1e-9:
        raise ValueError("Stray stores one camera matrix; this capture's intrinsics change per frame")
    root = Path(folder)
    (root / "depth").mkdir(parents=True, exist_ok=True)
    if capture.confidence is not None:
        (root / "confidence").mkdir(parents=True, exist_ok=True)
    fx, fy, cx, cy = k[0].tolist()
    (root / "camera_matrix.csv").write_text(f"{fx!r},0.0,{cx!r}\n0.0,{fy!r},{cy!r}\n0.0,0.0,1.0\n")
    q = matrix_to_quat_wxyz(capture.world_from_camera[:, :3, :3])
    lines = ["timestamp, frame, x, y, z, qx, qy, qz, qw"]
    for t, f in enumerate(capture.frame_ids.tolist()):
        x, y, z = capture.world_from_camera[t, :3, 3].tolist()
        qw, qx, qy, qz = q[t].tolist()
        values = [repr(float(capture.timestamps[t])), str(f)] + [repr(v) for v in (x, y, z, qx, qy, qz, qw)]
        lines.append(", ".join(values))
        (root / "depth" / f"{f:06d}.png").write_bytes(encode_png(depth_to_mm_png(capture.depth[t])))
        if capture.confidence is not None:
            (root / "confidence" / f"{f:06d}.png").write_bytes(encode_png(capture.confidence[t].astype(np.uint8)))
    (root / "odometry.csv").write_text("\n".join(lines) + "\n")

    ids = capture.frame_ids
    dt = np.diff(capture.timestamps) / np.maximum(np.diff(ids), 1)
    fps = float(1.0 / np.median(dt)) if dt.size and np.median(dt) > 0 else 60.0
    w, h = capture.rgb_size
    fourcc = cv2.VideoWriter_fourcc(*("FFV1" if lossless else "mp4v"))
    writer = cv2.VideoWriter(str(root / "rgb.mp4"), fourcc, fps, (w, h))
    if not writer.isOpened():
        raise RuntimeError(f"OpenCV cannot open a {'FFV1' if lossless else 'mp4v'} video writer")
    try:
        t = 0
        for f in range(int(ids[-1]) + 1):
            if t + 1 < len(ids) and ids[t + 1] <= f:
                t += 1
            writer.write(cv2.cvtColor(capture.rgb[t], cv2.COLOR_RGB2BGR))
    finally:
        writer.release()
    return root
