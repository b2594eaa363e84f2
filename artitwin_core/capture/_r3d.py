"""Record3D ``.r3d`` files: a ZIP archive with ``metadata`` (JSON), ``icon`` and per frame
``rgbd/<i>.jpg``, ``rgbd/<i>.depth`` (LZFSE float32 metres) and ``rgbd/<i>.conf`` (LZFSE uint8).

Entries are read straight from the archive (nothing is extracted), yet archives with entry names
that would escape an extraction folder are refused: they are not what Record3D writes, and
other tools may extract them. Every entry's declared size is checked before it is decompressed.
"""

from __future__ import annotations

import json
import re
import zipfile
from pathlib import Path, PurePosixPath

import cv2
import lzfse
import numpy as np

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
)
from artitwin_core.capture._lzfse import safe_decompress
from artitwin_core.capture._options import ReadOptions
from artitwin_core.capture._record3d_meta import build_metadata, default_depth_wh, parse_metadata
from artitwin_core.capture._types import Capture

FORMAT = "record3d-r3d"
_FRAME_ENTRY = re.compile(r"^rgbd/(\d+)\.(jpg|depth|conf)$")
_REEXPORT = "Export the recording from Record3D again (Share > .r3d) and copy it completely."


def unsafe_entry_reason(name: str) -> str | None:
    """Why a ZIP entry name could escape an extraction folder, or ``None`` if it cannot."""
    norm = name.replace("\\", "/")
    if norm.startswith("/") or re.match(r"^[A-Za-z]:", norm):
        return "is an absolute path"
    if ".." in PurePosixPath(norm).parts:
        return "contains '..'"
    if "\x00" in name:
        return "contains a NUL byte"
    return None


def _open_zip(path: Path) -> zipfile.ZipFile:
    try:
        zf = zipfile.ZipFile(path)
    except FileNotFoundError as exc:
        raise input_error(path, "the file does not exist", "Check the path.") from exc
    except (zipfile.BadZipFile, OSError) as exc:
        raise input_error(path, f"not a readable .r3d (ZIP) archive ({exc})", _REEXPORT) from exc
    for info in zf.infolist():
        why = unsafe_entry_reason(info.filename)
        if why is not None:
            zf.close()
            raise input_error(path, f"archive entry {info.filename!r} {why}; Record3D never writes such "
                              "entries and extracting it would write outside the target folder",
                              "Do not use this file; export the recording from Record3D again.")
    return zf


def _read_entry(zf: zipfile.ZipFile, info: zipfile.ZipInfo, path: Path, budget: ByteBudget,
                frame: int | None) -> bytes:
    budget.take(info.file_size, f"{path}!{info.filename}", frame)
    try:
        return zf.read(info)
    except (zipfile.BadZipFile, OSError, EOFError, ValueError, RuntimeError) as exc:  # RuntimeError: encrypted
        raise input_error(f"{path}!{info.filename}", f"the archive entry cannot be read ({exc})", _REEXPORT,
                          frame) from exc


def _frame_entries(zf: zipfile.ZipFile) -> dict[int, dict[str, zipfile.ZipInfo]]:
    frames: dict[int, dict[str, zipfile.ZipInfo]] = {}
    for info in zf.infolist():
        m = _FRAME_ENTRY.match(info.filename)
        if m:
            frames.setdefault(int(m.group(1)), {})[m.group(2)] = info
    return frames


def read_r3d(path: str | Path, options: ReadOptions | None = None) -> Capture:
    """Read a Record3D ``.r3d`` file into a :class:`Capture` (OpenCV axes, camera-to-world).

    File frame ``i`` (``rgbd/<i>.*``) takes ``poses[i]``; gaps in the numbering are allowed.
    Depth intrinsics are the RGB ones scaled to the depth size (:func:`depth_intrinsics_from_rgb`).
    """
    path = Path(path)
    options = options or ReadOptions()
    budget = ByteBudget(options)
    with _open_zip(path) as zf:
        try:
            meta_info = zf.getinfo("metadata")
        except KeyError as exc:
            raise input_error(path, "the archive has no 'metadata' entry", _REEXPORT) from exc
        meta_src = f"{path}!metadata"
        try:
            meta_json = json.loads(_read_entry(zf, meta_info, path, budget, None))
        except (UnicodeDecodeError, json.JSONDecodeError) as exc:
            raise input_error(meta_src, f"the metadata is not valid JSON ({exc})", _REEXPORT) from exc
        meta = parse_metadata(meta_json, meta_src)
        depth_wh = meta.depth_wh or default_depth_wh(meta.rgb_wh)

        entries = _frame_entries(zf)
        if not entries:
            raise input_error(path, "the archive has no rgbd/<i>.jpg frames", _REEXPORT)
        numbers = sorted(entries)
        for i in numbers:
            kinds = entries[i]
            for need in ("jpg", "depth"):
                if need not in kinds:
                    raise input_error(path, f"entry rgbd/{i}.{need} is missing", _REEXPORT, i)
            if i >= meta.num_poses:
                raise input_error(path, f"the archive holds frame files up to rgbd/{numbers[-1]}.jpg but the "
                                  f"metadata has only {meta.num_poses} poses (frames and poses do not match)",
                                  _REEXPORT, i)
        has_conf = ["conf" in entries[i] for i in numbers]
        if any(has_conf) and not all(has_conf):
            i = numbers[has_conf.index(False)]
            raise input_error(path, f"entry rgbd/{i}.conf is missing while other frames have one", _REEXPORT, i)

        picked = [numbers[p] for p in options.select(len(numbers))]
        check_capture_size(path, len(picked), meta.rgb_wh, depth_wh, options)
        n_depth = depth_wh[0] * depth_wh[1]
        rgb, depth, conf, poses, intr, stamps = [], [], [], [], [], []
        for i in picked:
            src = f"{path}!rgbd/{i}"
            if not options.skip_rgb:
                rgb.append(fit_rgb(decode_rgb(_read_entry(zf, entries[i]["jpg"], path, budget, i), src + ".jpg", i,
                                              meta.rgb_wh, budget), options))
            raw = _read_entry(zf, entries[i]["depth"], path, budget, i)
            budget.take(4 * n_depth, src + ".depth", i)
            try:
                d = np.frombuffer(safe_decompress(raw, 4 * n_depth), dtype="<f4").reshape(depth_wh[1], depth_wh[0])
            except ValueError as exc:
                hint = "" if meta.depth_wh else f" (the metadata has no dw/dh; assumed {depth_wh[0]}x{depth_wh[1]})"
                raise input_error(src + ".depth", f"the depth data is not {depth_wh[0]}x{depth_wh[1]} float32: "
                                  f"{exc}{hint}", _REEXPORT, i) from exc
            depth.append(clean_depth(d, src + ".depth", i, options))
            if has_conf[0]:
                raw = _read_entry(zf, entries[i]["conf"], path, budget, i)
                budget.take(n_depth, src + ".conf", i)
                try:
                    conf.append(np.frombuffer(safe_decompress(raw, n_depth), np.uint8).reshape(depth_wh[1], depth_wh[0]))
                except ValueError as exc:
                    raise input_error(src + ".conf", f"the confidence data is not {depth_wh[0]}x{depth_wh[1]} "
                                      f"uint8: {exc}", _REEXPORT, i) from exc
            pose = meta.world_from_camera(i, meta_src)
            check_pose(pose, meta_src, i)
            poses.append(pose)
            intr.append(meta.frame_intrinsics(i))
            stamps.append(meta.frame_time(i))
    rgb_intr = np.array(intr)
    return assemble(
        rgb=rgb, depth=depth, confidence=conf if has_conf[0] else None, rgb_intrinsics=rgb_intr,
        depth_intrinsics=depth_intrinsics_from_rgb(rgb_intr, meta.rgb_wh, depth_wh),
        world_from_camera=np.array(poses), timestamps=np.array(stamps), frame_ids=picked,
        distortion=None, source_format=FORMAT, options=options, rgb_source_wh=meta.rgb_wh,
        stream=meta.pose_stream(set(numbers), meta_src),
    )


def write_r3d(capture: Capture, path: str | Path) -> Path:
    """Write ``capture`` as a Record3D ``.r3d`` archive at ``path``; returns the path.

    JPEG quality 95, depth as LZFSE float32 (NaN = no measurement), confidence as LZFSE uint8
    (written only when the capture has it). Requires depth intrinsics derivable from the RGB ones
    (:func:`depth_intrinsics_from_rgb`): the format stores only K at RGB resolution.
    """
    check_capture_for_writing(capture)
    check_depth_intrinsics_derivable(capture, FORMAT)
    if capture.distortion is not None and np.any(capture.distortion != 0):
        raise ValueError("Record3D stores pinhole images; this capture has lens distortion")
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    meta = build_metadata(capture)
    with zipfile.ZipFile(path, "w") as zf:
        _put(zf, "metadata", json.dumps(meta), zipfile.ZIP_DEFLATED)
        icon = cv2.resize(capture.rgb[0], (max(1, capture.rgb_size[0] // 4), max(1, capture.rgb_size[1] // 4)),
                          interpolation=cv2.INTER_AREA)
        _put(zf, "icon", encode_jpeg(icon))
        for t, i in enumerate(capture.frame_ids.tolist()):
            _put(zf, f"rgbd/{i}.jpg", encode_jpeg(capture.rgb[t]))
            d = np.ascontiguousarray(capture.depth[t], dtype="<f4")
            _put(zf, f"rgbd/{i}.depth", lzfse.compress(d.tobytes()))
            if capture.confidence is not None:
                c = np.ascontiguousarray(capture.confidence[t], dtype=np.uint8)
                _put(zf, f"rgbd/{i}.conf", lzfse.compress(c.tobytes()))
    return path


# Every entry is dated zip's earliest date, not the time of writing: the archive's bytes then
# depend on the capture alone, so a scene written again (``artitwin synth``, the benchmarks) keeps
# its content key and a rerun on the same store reuses what was computed from it.
_ZIP_EPOCH = (1980, 1, 1, 0, 0, 0)


def _put(zf: zipfile.ZipFile, name: str, data: str | bytes, compress_type: int = zipfile.ZIP_STORED) -> None:
    info = zipfile.ZipInfo(name, date_time=_ZIP_EPOCH)
    info.compress_type = compress_type
    info.external_attr = 0o600 << 16  # as ZipFile.writestr(name) sets it
    zf.writestr(info, data)
