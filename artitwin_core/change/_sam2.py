"""Optional SAM2 video backend: propagate the last frame's part masks backwards with SAM2.

Used only when the user gives a local checkpoint and the ``sam2`` package imports; nothing is
downloaded. Written against SAM2's documented video predictor API
(``build_sam2_video_predictor``, ``init_state`` on a folder of JPEG frames, ``add_new_mask``,
``propagate_in_video(..., reverse=True)``); it cannot be exercised in CI, so only its
input checks are tested.
"""

from __future__ import annotations

import importlib
import tempfile
from pathlib import Path

import numpy as np

from artitwin_core._errors import InputError


def propagate_masks_sam2(
    rgb: np.ndarray,
    last_part_mask: np.ndarray,
    checkpoint: str | Path,
    *,
    model_config: str = "configs/sam2.1/sam2.1_hiera_l.yaml",
    device: str | None = None,
) -> np.ndarray:
    """Part labels for every frame from the last frame's labels, with SAM2 run in reverse.

    Args:
        rgb: ``[T, H, W, 3]`` uint8 frames of the dynamic recording.
        last_part_mask: ``[H, W]`` uint8 labels of the last frame (0 none, k + 1 part k).
        checkpoint: path to a local SAM2 checkpoint (``.pt``).
        model_config: the SAM2 config name matching the checkpoint.
        device: torch device; default CUDA when available, else CPU.

    Returns:
        ``[T, H, W]`` uint8 labels.

    Raises:
        InputError: the checkpoint is missing, ``sam2`` does not import, or the shapes disagree.
    """
    path = Path(checkpoint)
    if not path.is_file():
        raise InputError(
            f"SAM2 mask backend: checkpoint {str(path)!r} does not exist. Give the path of a downloaded SAM2 "
            "checkpoint (e.g. sam2.1_hiera_large.pt), or use the default geometric backend (no weights)."
        )
    rgb = np.asarray(rgb)
    last = np.asarray(last_part_mask)
    if rgb.ndim != 4 or rgb.shape[-1] != 3 or last.shape != rgb.shape[1:3]:
        raise InputError(
            f"SAM2 mask backend: rgb must be [T, H, W, 3] and last_part_mask [H, W]; got {rgb.shape} and {last.shape}."
        )
    try:
        build = importlib.import_module("sam2.build_sam").build_sam2_video_predictor
        torch = importlib.import_module("torch")
        image = importlib.import_module("PIL.Image")
    except ImportError as err:
        raise InputError(
            f"SAM2 mask backend: the 'sam2' package does not import ({err}). Install SAM2 "
            "(pip install sam2, with the checkpoint downloaded beforehand) or use the default geometric backend "
            "(leave part_masks.sam2_checkpoint unset)."
        ) from err
    dev = device or ("cuda" if torch.cuda.is_available() else "cpu")
    predictor = build(model_config, str(path), device=dev)
    n = rgb.shape[0]
    out = np.zeros(rgb.shape[:3], np.uint8)
    labels = [int(k) for k in np.unique(last) if k > 0]
    with tempfile.TemporaryDirectory(prefix="artitwin-sam2-") as tmp:
        for t in range(n):
            image.fromarray(rgb[t]).save(Path(tmp) / f"{t:05d}.jpg", quality=95)
        with torch.inference_mode():
            state = predictor.init_state(video_path=tmp)
            for k in labels:
                predictor.add_new_mask(state, frame_idx=n - 1, obj_id=k, mask=last == k)
            for t, obj_ids, logits in predictor.propagate_in_video(state, start_frame_idx=n - 1, reverse=True):
                for j, k in enumerate(obj_ids):
                    m = (logits[j, 0] > 0.0).cpu().numpy()
                    out[t][m & (out[t] == 0)] = k
    return out
