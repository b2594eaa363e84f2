"""What the part masks say, for people: overlay images of the masks on the frames and per-frame curves.

The change report shows where each moving part and the hand were labelled, at the frames that
matter (the first, each part's first moved frame, the last, where the parts are most visible,
and evenly between), so a user sees at a glance whether the masks follow the door or drawer as
it closes backwards through the recording and keep the hand apart.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from artitwin_core._errors import InputError
from artitwin_core.masks import MaskSequence

# Part k + 1 is drawn in PART_COLOURS[k % len]; the hand in HAND_COLOUR (sRGB).
PART_COLOURS = np.array(
    [[255, 140, 0], [0, 160, 255], [170, 60, 255], [0, 200, 120], [255, 60, 120], [200, 200, 0]], np.uint8
)
HAND_COLOUR = np.array([255, 40, 40], np.uint8)


@dataclass(frozen=True)
class ChangeSummary:
    """Per-frame curves and per-part figures of a mask sequence.

    Attributes:
        part_fraction: ``[K, T]`` share of each frame's pixels labelled part k + 1.
        hand_fraction: ``[T]`` share of each frame's pixels labelled hand.
        hand_overlap: ``[T]`` share of hand pixels also labelled a part (should be 0).
        first_seen: ``[K]`` first frame with at least ``min_pixels`` pixels of part k + 1 (-1 never).
        peak_frame: ``[K]`` frame where part k + 1 covers most pixels.
        frames: frames chosen for the overlay images, ascending.
    """

    part_fraction: np.ndarray
    hand_fraction: np.ndarray
    hand_overlap: np.ndarray
    first_seen: np.ndarray
    peak_frame: np.ndarray
    frames: list[int]


def summarize_masks(masks: MaskSequence, *, min_pixels: int = 50, max_images: int = 6) -> ChangeSummary:
    """Per-frame shares of part and hand pixels and the frames worth showing.

    Args:
        masks: ``part [T, H, W]`` labels, ``hand [T, H, W]``.
        min_pixels: a part counts as seen in a frame with at least this many pixels.
        max_images: at most this many frames are chosen for overlays.
    """
    part = np.asarray(masks.part)
    hand = np.asarray(masks.hand).astype(bool)
    if part.ndim != 3 or hand.shape != part.shape:
        raise InputError(
            f"summarize_masks: masks.part {part.shape} and masks.hand {hand.shape} must both be [T, H, W]; "
            "pass the masks of one recording."
        )
    t_count = part.shape[0]
    pixels = float(part.shape[1] * part.shape[2])
    k_count = int(part.max()) if part.size else 0
    counts = np.stack([(part == k + 1).reshape(t_count, -1).sum(1) for k in range(k_count)]) if k_count else np.zeros((0, t_count))
    hand_px = hand.reshape(t_count, -1).sum(1)
    overlap = (hand & (part > 0)).reshape(t_count, -1).sum(1)
    first = np.array([int(np.argmax(c >= min_pixels)) if np.any(c >= min_pixels) else -1 for c in counts], np.int64)
    peak = np.array([int(np.argmax(c)) for c in counts], np.int64)
    wanted = {0, t_count - 1, *[int(f) for f in first if f >= 0], *[int(p) for p in peak]}
    spare = max(max_images - len(wanted), 0)
    wanted |= {int(round(x)) for x in np.linspace(0, t_count - 1, spare + 2)[1:-1]}
    frames = sorted(wanted)
    if len(frames) > max_images:
        # Keep the first, the last and the parts' own frames before the evenly spaced ones.
        keep = [0, t_count - 1, *[int(f) for f in first if f >= 0], *[int(p) for p in peak]]
        frames = sorted(dict.fromkeys(keep))[:max_images]
    return ChangeSummary(
        part_fraction=counts / pixels,
        hand_fraction=hand_px / pixels,
        hand_overlap=np.where(hand_px > 0, overlap / np.maximum(hand_px, 1), 0.0),
        first_seen=first,
        peak_frame=peak,
        frames=frames,
    )


def mask_overlay(rgb: np.ndarray, part: np.ndarray, hand: np.ndarray, alpha: float = 0.5) -> np.ndarray:
    """``rgb [H, W, 3]`` uint8 with parts and hand tinted and outlined: ``[H, W, 3]`` uint8.

    ``part [H, W]`` labels (k + 1 drawn in ``PART_COLOURS[k]``), ``hand [H, W]`` bool (in
    ``HAND_COLOUR``); ``alpha`` is the tint's opacity."""
    rgb = np.asarray(rgb)
    part = np.asarray(part)
    hand = np.asarray(hand).astype(bool)
    if rgb.ndim != 3 or rgb.shape[2] != 3 or part.shape != rgb.shape[:2] or hand.shape != rgb.shape[:2]:
        raise InputError(
            f"mask_overlay: rgb {rgb.shape} must be [H, W, 3] and part {part.shape} / hand {hand.shape} [H, W]."
        )
    out = rgb.astype(np.float64)
    colour = np.zeros_like(out)
    tint = np.zeros(part.shape, bool)
    labelled = part > 0
    colour[labelled] = PART_COLOURS[(part[labelled].astype(np.int64) - 1) % len(PART_COLOURS)]
    colour[hand] = HAND_COLOUR
    tint = labelled | hand
    out[tint] = (1.0 - alpha) * out[tint] + alpha * colour[tint]
    # Outlines: a labelled pixel with a differently labelled 4-neighbour, drawn opaque.
    lab = np.where(hand, 255, part.astype(np.int64))
    edge = np.zeros(part.shape, bool)
    edge[1:, :] |= lab[1:, :] != lab[:-1, :]
    edge[:-1, :] |= lab[1:, :] != lab[:-1, :]
    edge[:, 1:] |= lab[:, 1:] != lab[:, :-1]
    edge[:, :-1] |= lab[:, 1:] != lab[:, :-1]
    edge &= tint
    out[edge] = colour[edge]
    return np.clip(np.rint(out), 0, 255).astype(np.uint8)
