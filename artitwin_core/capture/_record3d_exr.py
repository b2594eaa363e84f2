"""Record3D "EXR + JPG" export folders: ``metadata.json``, ``rgb/<i>.jpg`` and ``depth/<i>.exr``
(one float16 channel ``R``, metres). No confidence maps. Frames removed in the app leave gaps in
the numbering; file number ``i`` still takes ``poses[i]``.
"""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import OpenEXR

from artitwin_core.capture._common import (
    ByteBudget,
    assemble,
    check_capture_for_writing,
    check_capture_size,
    check_depth_intrinsics_derivable,
    check_pose,
    clean_depth,
    decode_rgb,
    depth_intrinsics_from_rgb,
    encode_jpeg,
    fit_rgb,
    input_error,
    read_file_bytes,
)
from artitwin_core.capture._options import ReadOptions
from artitwin_core.capture._record3d_meta import build_metadata, parse_metadata
from artitwin_core.capture._types import Capture

FORMAT = "record3d-exr"
_REEXPORT = "Export the recording from Record3D again (EXR + JPG) and copy the whole folder."


def _numbered(folder: Path, suffix: str) -> dict[int, Path]:
    out: dict[int, Path] = {}
    if folder.is_dir():
        for p in folder.iterdir():
            if p.suffix.lower() == suffix and p.stem.isdigit():
                out[int(p.stem)] = p
    return out


def exr_frame_files(root: Path) -> tuple[dict[int, Path], dict[int, Path]]:
    """``(rgb, depth)``: frame number -> file, for an export folder."""
    return _numbered(root / "rgb", ".jpg"), _numbered(root / "depth", ".exr")


def _read_exr_depth(path: Path, frame: int, expected_wh: tuple[int, int] | None, budget: ByteBudget
                    ) -> np.ndarray:
    try:
        size = path.stat().st_size
    except OSError as exc:
        raise input_error(path, "the depth file is missing or unreadable", _REEXPORT, frame) from exc
    budget.take(size, path, frame)
    try:
        header = OpenEXR.File(str(path), header_only=True).header()
        (x0, y0), (x1, y1) = header["dataWindow"]
        names = [c.name for c in header["channels"]]
    except Exception as exc:  # OpenEXR raises RuntimeError/OSError variants on damaged files
        raise input_error(path, f"not a readable EXR file ({exc})", _REEXPORT, frame) from exc
    wh = (int(x1) - int(x0) + 1, int(y1) - int(y0) + 1)
    if "R" not in names:
        raise input_error(path, f"the EXR has channels {names}, expected 'R' (depth in metres)", _REEXPORT, frame)
    if expected_wh is not None and wh != tuple(expected_wh):
        raise input_error(path, f"depth is {wh[0]}x{wh[1]} pixels, the recording's first frame "
                          f"{expected_wh[0]}x{expected_wh[1]}", "All depth maps of a recording must share "
                          "one size; " + _REEXPORT, frame)
    if not (1 <= wh[0] <= 16384 and 1 <= wh[1] <= 16384):
        raise input_error(path, f"the EXR declares {wh[0]}x{wh[1]} pixels", _REEXPORT, frame)
    budget.take(wh[0] * wh[1] * 4 * len(names), path, frame)
    try:
        pixels = OpenEXR.File(str(path), separate_channels=True).channels()["R"].pixels
    except Exception as exc:
        raise input_error(path, f"the EXR pixel data cannot be read ({exc})", _REEXPORT, frame) from exc
    return np.asarray(pixels, dtype=np.float32).reshape(wh[1], wh[0])


def read_record3d_exr(folder: str | Path, options: ReadOptions | None = None) -> Capture:
    """Read a Record3D EXR+JPG export folder into a :class:`Capture` (no confidence)."""
    root = Path(folder)
    options = options or ReadOptions()
    budget = ByteBudget(options)
    meta_path = root / "metadata.json"
    try:
        meta_json = json.loads(read_file_bytes(meta_path, budget))
    except (UnicodeDecodeError, json.JSONDecodeError) as exc:
        raise input_error(meta_path, f"not valid JSON ({exc})", _REEXPORT) from exc
    meta = parse_metadata(meta_json, meta_path)

    rgb_files, depth_files = exr_frame_files(root)
    if not rgb_files:
        raise input_error(root / "rgb", "no <i>.jpg frames found", _REEXPORT)
    numbers = sorted(set(rgb_files) | set(depth_files))
    for i in numbers:
        if i not in rgb_files:
            raise input_error(root / "rgb" / f"{i}.jpg", "the colour frame is missing (its depth exists)", _REEXPORT, i)
        if i not in depth_files:
            raise input_error(root / "depth" / f"{i}.exr", "the depth frame is missing (its colour image exists)",
                              _REEXPORT, i)
        if i >= meta.num_poses:
            raise input_error(rgb_files[i], f"frame files go up to number {numbers[-1]} but {meta_path.name} "
                              f"has only {meta.num_poses} poses (frames and poses do not match)", _REEXPORT, i)

    picked = [numbers[p] for p in options.select(len(numbers))]
    # The depth size is taken from the EXR files themselves rather than from dw/dh: the depth
    # intrinsics are derived from whatever size the export holds, so both are right either way.
    d0 = _read_exr_depth(depth_files[picked[0]], picked[0], None, budget)
    first_depth = (d0.shape[1], d0.shape[0])
    check_capture_size(root, len(picked), meta.rgb_wh, first_depth, options)
    rgb, depth, poses, intr, stamps = [], [], [], [], []
    for i in picked:
        if not options.skip_rgb:
            rgb.append(fit_rgb(decode_rgb(read_file_bytes(rgb_files[i], budget, i), rgb_files[i], i, meta.rgb_wh, budget),
                               options))
        d = d0 if i == picked[0] else _read_exr_depth(depth_files[i], i, first_depth, budget)
        depth.append(clean_depth(d, depth_files[i], i, options))
        pose = meta.world_from_camera(i, meta_path)
        check_pose(pose, meta_path, i)
        poses.append(pose)
        intr.append(meta.frame_intrinsics(i))
        stamps.append(meta.frame_time(i))
    rgb_intr = np.array(intr)
    return assemble(
        rgb=rgb, depth=depth, confidence=None, rgb_intrinsics=rgb_intr,
        depth_intrinsics=depth_intrinsics_from_rgb(rgb_intr, meta.rgb_wh, first_depth),
        world_from_camera=np.array(poses), timestamps=np.array(stamps), frame_ids=picked,
        distortion=None, source_format=FORMAT, options=options, rgb_source_wh=meta.rgb_wh,
        stream=meta.pose_stream(set(numbers), meta_path),
    )


def write_record3d_exr(capture: Capture, folder: str | Path) -> Path:
    """Write ``capture`` as a Record3D EXR+JPG export into ``folder``; returns the folder.

    JPEG quality 95; depth as float16 EXR channel ``R`` (about 3 significant digits: 0.5 mm at 1 m,
    2 mm at 4 m); confidence is dropped, as the app's export does.
    """
    check_capture_for_writing(capture)
    check_depth_intrinsics_derivable(capture, FORMAT)
    if capture.distortion is not None and np.any(capture.distortion != 0):
        raise ValueError("Record3D stores pinhole images; this capture has lens distortion")
    root = Path(folder)
    (root / "rgb").mkdir(parents=True, exist_ok=True)
    (root / "depth").mkdir(parents=True, exist_ok=True)
    (root / "metadata.json").write_text(json.dumps(build_metadata(capture)))
    header = {"compression": OpenEXR.ZIP_COMPRESSION, "type": OpenEXR.scanlineimage}
    for t, i in enumerate(capture.frame_ids.tolist()):
        (root / "rgb" / f"{i}.jpg").write_bytes(encode_jpeg(capture.rgb[t]))
        d16 = np.ascontiguousarray(capture.depth[t].astype(np.float16))
        OpenEXR.File(header, {"R": d16}).write(str(root / "depth" / f"{i}.exr"))
    return root
