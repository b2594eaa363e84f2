"""Per-part 3DGS ``.ply`` files: the twin split by Gaussian label, in the standard INRIA layout."""

from __future__ import annotations

from dataclasses import replace
from pathlib import Path

import numpy as np

from artitwin_core._errors import InputError
from artitwin_core.export._names import unique_names
from artitwin_core.gaussians import LABEL_BACKGROUND, LABEL_INTERIOR, LABEL_PART, GaussianParams


def export_part_plys(
    params: GaussianParams,
    out_dir: str | Path,
    *,
    part_names: list[str] | None = None,
    pivots: list[np.ndarray] | None = None,
) -> dict[str, Path]:
    """Write one 3DGS ``.ply`` per label present: ``background``, ``interior`` and each part.

    Args:
        params: the articulated twin's Gaussians (canonical frame, closed state); ``labels [N]``
            0 background, 1 interior, 2 + k part k.
        out_dir: output folder (created).
        part_names: a name per part index k (sanitised, as the URDF's link names are, so the two
            match when given the same names); default ``part_<k>``.
        pivots: ``[3]`` metres per part k; if given, part k's means are shifted by ``-pivot[k]`` into
            its URDF/MJCF link frame (link axes are the canonical axes, so rotations and SH stay).
            ``None`` keeps every file in the canonical frame.

    Returns:
        ``{name: path}`` of the files written (labels are dropped: the format has no field for them).
    """
    from artitwin_core.reconstruction import write_ply  # torch-heavy package: import on use only

    labels = np.asarray(params.labels)
    if labels.shape != (params.num_gaussians,):
        raise InputError(f"export_part_plys: labels has shape {labels.shape}; expected ({params.num_gaussians},).")
    part_ids = sorted(int(v) - LABEL_PART for v in np.unique(labels) if v >= LABEL_PART)
    num_parts = max(part_ids) + 1 if part_ids else 0
    if part_names is not None and len(part_names) < num_parts:
        raise InputError(f"export_part_plys: {len(part_names)} part_names for labels of {num_parts} parts.")
    if pivots is not None and len(pivots) < num_parts:
        raise InputError(f"export_part_plys: {len(pivots)} pivots for labels of {num_parts} parts.")
    names = unique_names(list(part_names) if part_names is not None else [f"part_{k}" for k in range(num_parts)],
                         reserved=("background", "interior"))
    out = Path(out_dir)
    written: dict[str, Path] = {}
    groups = [("background", LABEL_BACKGROUND, None), ("interior", LABEL_INTERIOR, None)]
    groups += [(names[k], LABEL_PART + k, k) for k in part_ids]
    for name, label, k in groups:
        keep = labels == label
        if not keep.any():
            continue
        sub = GaussianParams(
            means=np.asarray(params.means)[keep], quats_wxyz=np.asarray(params.quats_wxyz)[keep],
            log_scales=np.asarray(params.log_scales)[keep], opacity_logits=np.asarray(params.opacity_logits)[keep],
            sh=np.asarray(params.sh)[keep], labels=labels[keep],
        )
        if k is not None and pivots is not None:
            sub = replace(sub, means=(sub.means - np.asarray(pivots[k], np.float64)).astype(np.float32))
        written[name] = write_ply(out / f"{name}.ply", sub)
    return written
