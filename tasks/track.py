"""Stage: 3D point tracks on every moving part of the dynamic recording."""

from __future__ import annotations

import numpy as np

from artitwin_core.capture import Capture
from artitwin_core.masks import MaskSequence
from artitwin_core.tracking import TrackingConfig, track_part_points
from schemas import (
    CaptureArtifact,
    MaskSequenceArtifact,
    Registration,
    TrackingStageConfig,
    TrajectoriesArtifact,
)
from tasks._convert import config_map, to_core, to_core_config
from tasks._stage import stage

config_map(TrackingStageConfig, {TrackingConfig: {"max_tracks": "max_points"}})


@stage(name="track", version=7, config=TrackingStageConfig, output=TrajectoriesArtifact)
def track_parts(
    dynamic: CaptureArtifact, masks: MaskSequenceArtifact, registration: Registration, config: TrackingStageConfig
) -> TrajectoriesArtifact:
    """Tracks of each labelled part, lifted to the canonical frame; ``part_ids`` says whose. A part
    whose tracking fails gets no tracks and a note; the others are tracked all the same."""
    capture = to_core(Capture, dynamic)
    seq = to_core(MaskSequence, masks)
    labels = [int(v) for v in np.unique(seq.part) if v > 0]
    t = capture.num_frames
    pts, pix, valid, ids, query = [np.zeros((t, 0, 3))], [np.zeros((t, 0, 2), np.float32)], [np.zeros((t, 0), bool)], [], 0
    notes = []
    for label in labels:
        try:
            tr = track_part_points(capture, seq, registration.canonical_from_session, part_label=label,
                                   config=to_core_config(TrackingConfig, config))
        except Exception as e:  # noqa: BLE001 (one part's failure is that part's: settle_parts drops it, the rest go on)
            notes.append(f"mask label {label}: tracking failed ({type(e).__name__}: {e}); it has no tracks.")
            continue
        pts.append(tr.points_in_world)
        pix.append(tr.pixels.astype(np.float32))
        valid.append(tr.valid)
        ids.append(np.full(tr.valid.shape[1], label - 1, np.int32))
        query = tr.query_frame if len(ids) == 1 else query
    return TrajectoriesArtifact(
        points_in_world=np.concatenate(pts, axis=1),
        pixels=np.concatenate(pix, axis=1),
        valid=np.concatenate(valid, axis=1),
        query_frame=int(query),
        part_ids=np.concatenate(ids) if ids else np.zeros(0, np.int32),
        notes=notes,
    )
