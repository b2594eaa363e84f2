"""The three reconstruction stages, end to end on the tiny scene with a short schedule."""

from __future__ import annotations

import numpy as np

from schemas import CameraPoses, CaptureArtifact, GaussianCheckpoint, StageReport
from schemas._reconstruct import PoseRefineStageConfig, ReconstructConfig
from tasks import to_artifact
from tasks.reconstruct import reconstruct_canonical, reconstruct_report, refine_capture_poses


def test_stages_end_to_end(tiny_scene):
    capture = to_artifact(CaptureArtifact, tiny_scene.static)
    poses = refine_capture_poses(capture, PoseRefineStageConfig())
    assert isinstance(poses, CameraPoses) and poses.frame == "canonical"
    assert poses.world_from_camera.shape == (12, 4, 4)
    if poses.correction_translation is not None:  # refined: corrections are small on exact poses
        assert float(np.max(poses.correction_translation)) < 0.15
    config = ReconstructConfig(steps=20, max_init_points=3000)
    ckpt = reconstruct_canonical(capture, poses, config)
    assert isinstance(ckpt, GaussianCheckpoint) and ckpt.step == 20
    assert ckpt.sh.shape[1:] == (16, 3) and ckpt.means.shape[0] > 1000
    assert np.isfinite(ckpt.means).all() and np.isfinite(ckpt.sh).all()
    report = reconstruct_report(capture, poses, ckpt, config)
    assert isinstance(report, StageReport)
    m = report.metrics
    assert m["heldout_frames_count"] == 2.0  # frames 0 and 8 of 12
    assert m["gaussians_count"] == ckpt.means.shape[0]
    assert 10.0 < m["heldout_psnr_db"] < 60.0  # a real rendering, not a blank image
    assert 0.0 < m["heldout_depth_mae_m"] < 0.2
