"""Pieces every reader and writer shares: errors, image decoding with size checks, pose and
depth validation, intrinsics scaling, and assembling the final :class:`Capture`."""

from __future__ import annotations

import dataclasses
import io
import re
from collections.abc import Sequence
from pathlib import Path

import cv2
import numpy as np
from PIL import Image

from artitwin_core._errors import InputError
from artitwin_core.capture._options import MAX_SIDE_PIXELS, ReadOptions
from artitwin_core.capture._types import Capture
from artitwin_core.geometry import check_rigid

JPEG_QUALITY = 95
_DIGITS = re.compile(r"(\d+)")


def input_error(source: str | Path, what: str, todo: str, frame: int | None = None) -> InputError:
    """An :class:`InputError` whose message reads ``<file>, frame <n>: <what>. <todo>``."""
    where = f"{source}" if frame is None else f"{source}, frame {frame}"
    return InputError(f"{where}: {what}. {todo}")


def check_side(source: str | Path, field: str, value: object) -> int:
    """A positive image side length in pixels from a metadata field, or :class:`InputError`."""
    if isinstance(value, bool) or not isinstance(value, int | float) or value != int(value):
        raise input_error(source, f"field {field!r} is {value!r}, expected an integer pixel count",
                          "Re-export the recording; the metadata is damaged.")
    v = int(value)
    if not 1 <= v <= MAX_SIDE_PIXELS:
        raise input_error(source, f"field {field!r} is {v} pixels, outside 1..{MAX_SIDE_PIXELS}",
                          "The metadata is damaged or not from a supported app; re-export the recording.")
    return v


def frame_number(name: str) -> int | None:
    """The last run of digits in a file stem (``frame_00012`` -> 12), or ``None``."""
    found = _DIGITS.findall(Path(name).stem)
    return int(found[-1]) if found else None


class ByteBudget:
    """Counts decompressed bytes against :class:`ReadOptions` limits, before they are produced."""

    def __init__(self, options: ReadOptions) -> None:
        self.options = options
        self.used = 0

    def take(self, nbytes: int, source: str | Path, frame: int | None = None) -> None:
        if nbytes > self.options.max_frame_bytes:
            raise input_error(
                source, f"would decompress to {nbytes} bytes, above the limit of "
                f"{self.options.max_frame_bytes} bytes per file (ReadOptions.max_frame_bytes)",
                "The file may be a decompression bomb; if it is genuine, raise the limit.", frame)
        self.used += int(nbytes)
        if self.used > self.options.max_total_bytes:
            raise input_error(
                source, f"reading it brings the decompressed total to {self.used} bytes, above "
                f"ReadOptions.max_total_bytes = {self.options.max_total_bytes}",
                "Read fewer frames (stride, max_frames, rgb_max_width) or raise the limit.", frame)


def check_capture_size(source: str | Path, n: int, rgb_wh: tuple[int, int], depth_wh: tuple[int, int],
                       options: ReadOptions) -> None:
    """Refuse to allocate a :class:`Capture` larger than ``options.max_total_bytes``."""
    w, h = (0, 0) if options.skip_rgb else options.rgb_size(*rgb_wh)
    per_frame = w * h * 3 + depth_wh[0] * depth_wh[1] * 5
    if n * per_frame > options.max_total_bytes:
        raise input_error(
            source, f"{n} frames of {rgb_wh[0]}x{rgb_wh[1]} RGB and {depth_wh[0]}x{depth_wh[1]} depth "
            f"need {n * per_frame} bytes in memory, above ReadOptions.max_total_bytes",
            "Read fewer frames (stride, max_frames, rgb_max_width) or raise the limit.")


def decode_rgb(data: bytes, source: str | Path, frame: int, expected_wh: tuple[int, int] | None,
               budget: ByteBudget) -> np.ndarray:
    """Decode a JPEG/PNG colour image to ``[H, W, 3]`` uint8 RGB, checking its size first.

    The size is read from the header (PIL opens lazily) so a huge declared image is refused
    before any pixel is decoded.
    """
    try:
        with Image.open(io.BytesIO(data)) as im:
            wh = im.size
    except Exception as exc:  # PIL raises many types for damaged files
        raise input_error(source, f"cannot read the image header ({exc})",
                          "The frame is damaged; re-export the recording or remove the frame.", frame) from exc
    if expected_wh is not None and tuple(wh) != tuple(expected_wh):
        raise input_error(source, f"image is {wh[0]}x{wh[1]} pixels, the metadata says "
                          f"{expected_wh[0]}x{expected_wh[1]}",
                          "Frames of one recording must share a size; re-export the recording.", frame)
    if max(wh) > MAX_SIDE_PIXELS:
        raise input_error(source, f"image is {wh[0]}x{wh[1]} pixels, above {MAX_SIDE_PIXELS} a side",
                          "This is not a phone capture frame; check the file.", frame)
    budget.take(wh[0] * wh[1] * 3, source, frame)
    bgr = cv2.imdecode(np.frombuffer(data, np.uint8), cv2.IMREAD_COLOR | cv2.IMREAD_IGNORE_ORIENTATION)
    if bgr is None or bgr.shape[:2] != (wh[1], wh[0]):
        raise input_error(source, "the image data cannot be decoded",
                          "The frame is damaged; re-export the recording or remove the frame.", frame)
    return cv2.cvtColor(bgr, cv2.COLOR_BGR2RGB)


def encode_jpeg(rgb: np.ndarray) -> bytes:
    """``[H, W, 3]`` uint8 RGB to JPEG bytes at quality 95 (what Record3D writes)."""
    ok, buf = cv2.imencode(".jpg", cv2.cvtColor(np.ascontiguousarray(rgb), cv2.COLOR_RGB2BGR),
                           [cv2.IMWRITE_JPEG_QUALITY, JPEG_QUALITY])
    if not ok:
        raise RuntimeError("JPEG encoding failed")
    return buf.tobytes()


def read_file_bytes(path: Path, budget: ByteBudget, frame: int | None = None) -> bytes:
    """Read a whole file, refusing files above the per-file limit and missing files."""
    try:
        size = path.stat().st_size
    except OSError as exc:
        raise input_error(path, "the file is missing or unreadable",
                          "Check that the recording was copied completely.", frame) from exc
    budget.take(size, path, frame)
    try:
        return path.read_bytes()
    except OSError as exc:
        raise input_error(path, f"the file cannot be read ({exc})",
                          "Check the file permissions and that the copy is complete.", frame) from exc


def decode_png_depth(data: bytes, source: str | Path, frame: int, expected_wh: tuple[int, int] | None,
                     budget: ByteBudget, dtype: type = np.uint16) -> np.ndarray:
    """Decode a single-channel PNG (uint16 depth or uint8 confidence) to ``[h, w]``."""
    try:
        with Image.open(io.BytesIO(data)) as im:
            wh = im.size
    except Exception as exc:
        raise input_error(source, f"cannot read the PNG header ({exc})",
                          "The frame is damaged; re-export the recording.", frame) from exc
    if expected_wh is not None and tuple(wh) != tuple(expected_wh):
        raise input_error(source, f"map is {wh[0]}x{wh[1]} pixels, expected {expected_wh[0]}x{expected_wh[1]}",
                          "All depth/confidence maps of a recording must share one size.", frame)
    budget.take(wh[0] * wh[1] * 2, source, frame)
    img = cv2.imdecode(np.frombuffer(data, np.uint8), cv2.IMREAD_UNCHANGED)
    if img is None:
        raise input_error(source, "the PNG cannot be decoded", "The frame is damaged; re-export it.", frame)
    if img.ndim == 3:
        # Some tools save depth as 3 identical channels; take the first (channel 0 is B in cv2 order,
        # identical by construction).
        img = img[..., 0]
    if img.dtype != np.dtype(dtype):
        raise input_error(source, f"PNG holds {img.dtype} pixels, expected {np.dtype(dtype)}",
                          "Depth PNGs must be 16-bit millimetres; confidence PNGs 8-bit 0/1/2.", frame)
    return img


def encode_png(img: np.ndarray) -> bytes:
    ok, buf = cv2.imencode(".png", np.ascontiguousarray(img))
    if not ok:
        raise RuntimeError("PNG encoding failed")
    return buf.tobytes()


def clean_depth(depth: np.ndarray, source: str | Path, frame: int, options: ReadOptions) -> np.ndarray:
    """``[h, w]`` depth in metres as float32 with every non-finite or non-positive value set to NaN."""
    d = np.asarray(depth, dtype=np.float32).copy()
    d[~(np.isfinite(d) & (d > 0))] = np.nan
    if not options.allow_empty_depth and not np.any(np.isfinite(d)):
        raise input_error(source, "the depth map has no valid pixel (all zero, NaN or negative)",
                          "Remove this frame from the recording, or pass "
                          "ReadOptions(allow_empty_depth=True) to keep it.", frame)
    return d


def check_pose(world_from_camera: np.ndarray, source: str | Path, frame: int) -> None:
    why = check_rigid(world_from_camera)
    if why is not None:
        raise input_error(source, f"the camera pose is not a rigid transform: {why}",
                          "The tracking data is damaged; re-export the recording or drop this frame.", frame)


def scale_intrinsics(fx_fy_cx_cy: np.ndarray, sx: float, sy: float) -> np.ndarray:
    """Intrinsics ``[..., 4]`` for an image resampled by ``(sx, sy)`` (new size / old size).

    Uses the pixel-centre convention (pixel ``i`` covers ``[i - 0.5, i + 0.5]``), so
    ``c' = (c + 0.5) * s - 0.5``: exact for area resampling by any factor.
    """
    p = np.asarray(fx_fy_cx_cy, dtype=np.float64).copy()
    p[..., 0] *= sx
    p[..., 1] *= sy
    p[..., 2] = (p[..., 2] + 0.5) * sx - 0.5
    p[..., 3] = (p[..., 3] + 0.5) * sy - 0.5
    return p


def depth_intrinsics_from_rgb(rgb_intrinsics: np.ndarray, rgb_size: tuple[int, int],
                              depth_size: tuple[int, int]) -> np.ndarray:
    """Depth intrinsics ``[..., 4]`` from RGB intrinsics ``[..., 4]`` for sizes ``(width, height)``.

    The depth map covers the same field of view as the RGB image (ARKit, Stray, Record3D), so K
    is scaled by ``(dw / w, dh / h)`` with the pixel-centre convention of :func:`scale_intrinsics`.
    Writers of formats that store only RGB intrinsics require the capture to follow this.
    """
    return scale_intrinsics(rgb_intrinsics, depth_size[0] / rgb_size[0], depth_size[1] / rgb_size[1])


def check_depth_intrinsics_derivable(capture: Capture, fmt: str, tol_px: float = 1e-3) -> None:
    """Writers: refuse captures whose depth intrinsics the format cannot represent."""
    derived = depth_intrinsics_from_rgb(capture.rgb_intrinsics, capture.rgb_size, capture.depth_size)
    err = float(np.max(np.abs(derived - capture.depth_intrinsics))) if capture.num_frames else 0.0
    if err > tol_px:
        raise ValueError(
            f"{fmt} stores only RGB intrinsics; this capture's depth intrinsics differ by {err:.3g} px "
            "from depth_intrinsics_from_rgb(rgb_intrinsics, rgb_size, depth_size). Build the capture "
            "with that function.")


def check_capture_for_writing(capture: Capture) -> None:
    """Shapes and dtypes a writer relies on (a programming error if violated: ValueError)."""
    t = capture.num_frames
    if t < 1:
        raise ValueError("cannot write a capture with no frames")
    if capture.rgb.dtype != np.uint8 or capture.rgb.ndim != 4 or capture.rgb.shape[3] != 3:
        raise ValueError(f"rgb must be [T, H, W, 3] uint8, got {capture.rgb.shape} {capture.rgb.dtype}")
    if capture.depth.ndim != 3 or capture.depth.shape[0] != t:
        raise ValueError(f"depth must be [T, h, w], got {capture.depth.shape}")
    for name, arr, shape in [("rgb_intrinsics", capture.rgb_intrinsics, (t, 4)),
                             ("depth_intrinsics", capture.depth_intrinsics, (t, 4)),
                             ("world_from_camera", capture.world_from_camera, (t, 4, 4)),
                             ("timestamps", capture.timestamps, (t,)), ("frame_ids", capture.frame_ids, (t,))]:
        if np.shape(arr) != shape:
            raise ValueError(f"{name} must have shape {shape}, got {np.shape(arr)}")
    ids = np.asarray(capture.frame_ids)
    if np.any(ids < 0) or np.any(np.diff(ids) <= 0):
        raise ValueError("frame_ids must be non-negative and strictly increasing")


def downscale_rgb(capture: Capture, max_side: int | None) -> Capture:
    """``capture`` with its RGB frames downscaled (area interpolation) so that their longer side is
    at most ``max_side`` pixels, and the RGB intrinsics scaled to match (depth untouched); the
    capture itself when it is already that small or ``max_side`` is None."""
    if max_side is None:
        return capture
    w, h = capture.rgb_size
    nw, nh = ReadOptions(rgb_max_side=int(max_side)).rgb_size(w, h)
    if (nw, nh) == (w, h):
        return capture
    rgb = np.empty((capture.num_frames, nh, nw, 3), np.uint8)
    for t in range(capture.num_frames):
        rgb[t] = cv2.resize(capture.rgb[t], (nw, nh), interpolation=cv2.INTER_AREA)
    return dataclasses.replace(capture, rgb=rgb, rgb_intrinsics=scale_intrinsics(capture.rgb_intrinsics, nw / w, nh / h))


def fit_rgb(frame: np.ndarray, options: ReadOptions) -> np.ndarray:
    """A decoded ``[H, W, 3]`` frame at the size ``options`` reads (area interpolation), right
    after decoding, so that only the working resolution is ever held."""
    h, w = frame.shape[:2]
    nw, nh = options.rgb_size(w, h)
    if (nw, nh) == (w, h):
        return frame
    return cv2.resize(frame, (nw, nh), interpolation=cv2.INTER_AREA)


@dataclasses.dataclass(frozen=True)
class PoseStream:
    """Every pose a recording holds (``Capture.stream_*``): frame numbers ``[S]``, seconds ``[S]``
    and OpenCV camera-to-world ``[S, 4, 4]``, in frame order."""

    frame_ids: np.ndarray
    timestamps: np.ndarray
    world_from_camera: np.ndarray


def pose_stream(frame_ids: Sequence[int], timestamps: Sequence[float], world_from_camera: Sequence[np.ndarray],
                with_frames: Sequence[bool]) -> PoseStream:
    """The pose stream of a recording from all its pose rows: ``frame_ids [N]``, ``timestamps
    [N]``, ``world_from_camera [N, 4, 4]`` (a row that is ``None`` or not rigid is left out: a pose
    of a frame not read does not stop the read) and ``with_frames [N]``, whether a row's frame is
    in the files. A row without a frame that repeats a neighbour's pose exactly is left out too:
    an exporter's filler for a removed frame (ArtiTwin's own Record3D writer once wrote them),
    not a pose that was recorded. Rows whose time does not increase are left out."""
    keep_ids, keep_ts, keep_poses = [], [], []
    rows = list(world_from_camera)
    for k, (fid, ts, pose, framed) in enumerate(zip(frame_ids, timestamps, rows, with_frames, strict=True)):
        if pose is None or not np.all(np.isfinite(pose)) or not np.isfinite(ts):
            continue
        if not framed and any(0 <= j < len(rows) and rows[j] is not None and np.array_equal(rows[j], pose)
                              for j in (k - 1, k + 1)):
            continue
        if check_rigid(pose) is not None:
            continue
        if keep_ts and ts <= keep_ts[-1]:
            continue
        keep_ids.append(int(fid))
        keep_ts.append(float(ts))
        keep_poses.append(np.asarray(pose, np.float64))
    return PoseStream(np.asarray(keep_ids, np.int64), np.asarray(keep_ts, np.float64),
                      np.asarray(keep_poses, np.float64).reshape(-1, 4, 4))


def assemble(
    *,
    rgb: Sequence[np.ndarray],
    depth: Sequence[np.ndarray],
    confidence: Sequence[np.ndarray] | None,
    rgb_intrinsics: np.ndarray,
    depth_intrinsics: np.ndarray,
    world_from_camera: np.ndarray,
    timestamps: np.ndarray,
    frame_ids: Sequence[int],
    distortion: np.ndarray | None,
    source_format: str,
    options: ReadOptions,
    rgb_source_wh: tuple[int, int] | None = None,
    stream: PoseStream | None = None,
) -> Capture:
    """Stack per-frame arrays into a :class:`Capture` at the RGB size the options ask.

    ``rgb_intrinsics`` are at the stored size ``rgb_source_wh`` (default: the frames' own size).
    Frames already at the options' size (:func:`fit_rgb`) are kept; larger ones are downscaled
    here. With ``options.skip_rgb`` the frames are not given and ``rgb`` becomes a read-only
    zero view of the size a full read gives. ``stream`` (all the recording's poses) is kept
    when it holds a pose of a frame not read, and holds every frame read at its own pose and time."""
    rgb_intr = np.asarray(rgb_intrinsics, dtype=np.float64).reshape(-1, 4)
    frames = list(rgb)
    n = len(depth)
    if rgb_source_wh is None:
        if not frames:
            raise ValueError("assemble: give rgb_source_wh when no RGB frames are given")
        rgb_source_wh = (frames[0].shape[1], frames[0].shape[0])
    w, h = (int(v) for v in rgb_source_wh)
    nw, nh = options.rgb_size(w, h)
    if options.skip_rgb:
        stacked = np.broadcast_to(np.zeros((1, 1, 1, 3), np.uint8), (n, nh, nw, 3))
    else:
        frames = [f if f.shape[:2] == (nh, nw) else cv2.resize(f, (nw, nh), interpolation=cv2.INTER_AREA) for f in frames]
        stacked = np.stack(frames).astype(np.uint8, copy=False)
    if (nw, nh) != (w, h):
        rgb_intr = scale_intrinsics(rgb_intr, nw / w, nh / h)
    return Capture(
        rgb=stacked,
        depth=np.stack(depth).astype(np.float32, copy=False),
        confidence=None if confidence is None else np.stack(confidence).astype(np.uint8, copy=False),
        rgb_intrinsics=rgb_intr,
        depth_intrinsics=np.asarray(depth_intrinsics, dtype=np.float64).reshape(-1, 4),
        world_from_camera=np.asarray(world_from_camera, dtype=np.float64).reshape(-1, 4, 4),
        timestamps=np.asarray(timestamps, dtype=np.float64).reshape(-1),
        frame_ids=np.asarray(frame_ids, dtype=np.int64).reshape(-1),
        distortion=None if distortion is None else np.asarray(distortion, dtype=np.float64),
        source_format=source_format,
        **_stream_fields(stream, np.asarray(frame_ids, np.int64).reshape(-1),
                         np.asarray(timestamps, np.float64).reshape(-1),
                         np.asarray(world_from_camera, np.float64).reshape(-1, 4, 4)),
    )


def _stream_fields(stream: PoseStream | None, frame_ids: np.ndarray, timestamps: np.ndarray,
                   world_from_camera: np.ndarray) -> dict:
    """``Capture``'s ``stream_*`` fields: empty unless ``stream`` adds poses to the frames' and
    agrees with them (each frame's pose and time in it)."""
    if (stream is None or stream.frame_ids.size < 2 or not np.isin(frame_ids, stream.frame_ids).all()
            or np.isin(stream.frame_ids, frame_ids).all()):
        return {}  # none, one that misses a frame read, or one that adds no pose
    at = np.searchsorted(stream.frame_ids, frame_ids)
    same = (np.allclose(stream.timestamps[at], timestamps, atol=1e-9)
            and np.allclose(stream.world_from_camera[at], world_from_camera, atol=1e-9))
    if not same:
        return {}
    return {"stream_world_from_camera": stream.world_from_camera, "stream_timestamps": stream.timestamps,
            "stream_frame_ids": stream.frame_ids}
