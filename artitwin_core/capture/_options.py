"""Reader options: frame selection, RGB downscaling and limits against decompression bombs."""

from __future__ import annotations

from dataclasses import dataclass

from artitwin_core._errors import InputError

# A 48 MP (8064x6048) photo is the largest frame a phone makes today; 16384 pixels a side leaves
# room for that while rejecting metadata that claims 10^6 x 10^6 pixels.
MAX_SIDE_PIXELS = 16384


@dataclass(frozen=True)
class ReadOptions:
    """How to read a capture.

    Attributes:
        stride: keep every ``stride``-th frame of those present (>= 1).
        max_frames: keep at most this many frames after striding (``None``: all).
        rgb_max_width: downscale RGB (area interpolation) so its width is at most this many
            pixels; RGB intrinsics are scaled with the pixel-centre convention
            (``c' = (c + 0.5) * s - 0.5``). ``None`` keeps the stored resolution.
        rgb_max_side: downscale RGB likewise so its longer side is at most this many pixels
            (portrait and landscape alike); with ``rgb_max_width`` too, the smaller size wins.
            Each frame is downscaled as soon as it is decoded: a recording never sits in memory
            at its stored resolution.
        frames: read only these positions of the frames ``stride`` and ``max_frames`` select
            (e.g. keyframes chosen from a ``skip_rgb`` read); ``None`` reads them all.
        skip_rgb: read poses, intrinsics, timestamps, depth and confidence only; the returned
            capture's ``rgb`` is a read-only all-zero view of the size a full read would give
            (no memory), for choosing frames before any image is decoded.
        max_frame_bytes: largest decompressed size in bytes allowed for one stored file or
            archive entry (an image, a depth map, the metadata). Checked before decompressing.
        max_total_bytes: largest total in bytes allowed for the decompressed entries read and
            for the arrays of the returned :class:`Capture`. Checked before decoding frames.
        allow_empty_depth: accept frames whose depth map has no valid pixel (by default they
            raise :class:`InputError`: an all-invalid depth map usually means a broken export).
    """

    stride: int = 1
    max_frames: int | None = None
    rgb_max_width: int | None = None
    rgb_max_side: int | None = None
    frames: tuple[int, ...] | None = None
    skip_rgb: bool = False
    max_frame_bytes: int = 256 * 2**20
    max_total_bytes: int = 32 * 2**30
    allow_empty_depth: bool = False

    def __post_init__(self) -> None:
        if int(self.stride) < 1:
            raise InputError(f"ReadOptions.stride is {self.stride}; use an integer >= 1")
        if self.max_frames is not None and int(self.max_frames) < 1:
            raise InputError(f"ReadOptions.max_frames is {self.max_frames}; use None or an integer >= 1")
        if self.rgb_max_width is not None and int(self.rgb_max_width) < 8:
            raise InputError(f"ReadOptions.rgb_max_width is {self.rgb_max_width}; use None or >= 8 pixels")
        if self.rgb_max_side is not None and int(self.rgb_max_side) < 8:
            raise InputError(f"ReadOptions.rgb_max_side is {self.rgb_max_side}; use None or >= 8 pixels")
        if self.frames is not None and (len(self.frames) == 0 or min(self.frames) < 0):
            raise InputError("ReadOptions.frames must name at least one frame, by non-negative positions")
        if self.max_frame_bytes < 1 or self.max_total_bytes < 1:
            raise InputError("ReadOptions.max_frame_bytes and max_total_bytes must be positive")

    def select(self, n: int) -> list[int]:
        """Positions (into ``n`` available frames, sorted by frame number) that this reads."""
        picked = list(range(0, n, int(self.stride)))
        if self.max_frames is not None:
            picked = picked[: int(self.max_frames)]
        if self.frames is not None:
            if max(self.frames) >= len(picked):
                raise InputError(
                    f"ReadOptions.frames names position {max(self.frames)} but only {len(picked)} frames are "
                    "selected (after stride and max_frames); choose frames from a read with the same options."
                )
            picked = [picked[int(i)] for i in sorted(set(self.frames))]
        return picked

    def rgb_size(self, width: int, height: int) -> tuple[int, int]:
        """``(width, height)`` in pixels that RGB frames stored at ``width x height`` are read at
        (``rgb_max_width`` and ``rgb_max_side``; never upscaled; the aspect ratio kept)."""
        scale = 1.0
        if self.rgb_max_width is not None and width > self.rgb_max_width:
            scale = min(scale, self.rgb_max_width / width)
        if self.rgb_max_side is not None and max(width, height) > self.rgb_max_side:
            scale = min(scale, self.rgb_max_side / max(width, height))
        if scale >= 1.0:
            return int(width), int(height)
        if self.rgb_max_width is not None and scale == self.rgb_max_width / width:
            return int(self.rgb_max_width), max(1, round(height * scale))  # as rgb_max_width always gave
        return max(1, round(width * scale)), max(1, round(height * scale))
