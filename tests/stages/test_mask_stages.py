"""The part-mask stages on the tiny scene: the change report's figures against the true masks,
and the SAM2 backend chosen by config failing clearly when its checkpoint is missing."""

from __future__ import annotations

import numpy as np
import pytest

from artitwin_core import InputError
from artitwin_core.synth import BENCHMARK_SCENES, generate_scene
from schemas import CameraPoses, CaptureArtifact, MaskSequenceArtifact, PartMasksConfig, Registration
from tasks import to_artifact
from tasks.register import label_parts, part_masks_report


@pytest.fixture(scope="module")
def tiny():
    scene = generate_scene(BENCHMARK_SCENES["tiny"])
    truth = scene.truth
    registration = Registration(
        canonical_from_session=truth.canonical_from_dynamic_session, residual_m=0.003, inlier_fraction=0.9,
        method="ground truth",
    )
    return scene, registration


def test_report_describes_the_true_masks(tiny):
    scene, registration = tiny
    truth = scene.truth
    t_count = scene.dynamic.num_frames
    masks = MaskSequenceArtifact(part=truth.part_masks, hand=truth.hand_masks, score=np.ones(t_count, np.float32))
    report = part_masks_report(to_artifact(CaptureArtifact, scene.dynamic), masks, registration, PartMasksConfig())
    m = report.metrics
    assert m["parts_count"] == 1
    assert m["hand_labelled_part_frac"] == 0.0  # true masks never label the hand
    assert m["registration_residual_m"] == 0.003
    share = (truth.part_masks == 1).reshape(t_count, -1).mean(1)
    np.testing.assert_allclose(report.per_frame["part_0_frac"], share)
    assert m["part_0_peak_frac"] == pytest.approx(share.max())
    assert m["part_0_first_seen_index"] == float(np.argmax((truth.part_masks == 1).reshape(t_count, -1).sum(1) >= 50))
    assert 3 <= len(report.images) <= 6
    assert report.images[0].pixels.shape == scene.dynamic.rgb.shape[1:]
    assert report.images[0].caption.startswith("frame 0:")
    # Where the door is labelled, the overlay differs from the frame; elsewhere it is the frame.
    last = int(report.images[-1].caption.split(":")[0].split()[1])
    diff = np.any(report.images[-1].pixels != scene.dynamic.rgb[last], axis=-1)
    labelled = (truth.part_masks[last] > 0) | truth.hand_masks[last]
    assert not diff[~labelled].any() and diff[labelled].mean() > 0.9


def test_report_says_when_nothing_moved(tiny):
    scene, registration = tiny
    t_count, h, w = scene.dynamic.rgb.shape[:3]
    empty = MaskSequenceArtifact(
        part=np.zeros((t_count, h, w), np.uint8), hand=np.zeros((t_count, h, w), bool), score=np.zeros(t_count, np.float32)
    )
    report = part_masks_report(to_artifact(CaptureArtifact, scene.dynamic), empty, registration, PartMasksConfig())
    assert report.metrics["parts_count"] == 0
    assert any("No moving part" in n for n in report.notes)


def test_sam2_backend_without_its_checkpoint_is_a_clear_error(tiny, tmp_path):
    scene, registration = tiny
    poses = CameraPoses(
        world_from_camera=scene.static.world_from_camera, frame_ids=np.asarray(scene.static.frame_ids), frame="canonical"
    )
    config = PartMasksConfig(sam2_checkpoint=str(tmp_path / "sam2.1_hiera_large.pt"))
    with pytest.raises(InputError, match="sam2_checkpoint .*sam2.1_hiera_large.pt.* does not exist"):
        label_parts(
            to_artifact(CaptureArtifact, scene.static), poses, to_artifact(CaptureArtifact, scene.dynamic),
            registration, config,
        )
