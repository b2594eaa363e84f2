"""The articulate and articulate_report stages through their typed artifacts."""

from __future__ import annotations

import numpy as np
import pytest

from artitwin_core._errors import InputError
from artitwin_core.gaussians import LABEL_PART
from schemas import (
    CameraPoses,
    CaptureArtifact,
    GaussianCheckpoint,
    JointParams,
    JointSet,
    MaskSequenceArtifact,
    Registration,
)
from schemas._articulate import ArticulateConfig
from tasks._convert import to_artifact
from tasks.articulate import articulate_report, articulate_twin


@pytest.fixture(scope="module")
def inputs(tiny_scene, true_masks, canonical):
    truth = tiny_scene.truth
    static = to_artifact(CaptureArtifact, tiny_scene.static)
    poses = CameraPoses(
        world_from_camera=truth.static_world_from_camera,
        frame_ids=tiny_scene.static.frame_ids,
        frame="canonical",
    )
    # The dynamic capture keeps its session-frame poses; the registration maps them (true here).
    registration = Registration(
        canonical_from_session=truth.canonical_from_dynamic_session,
        residual_m=0.0,
        inlier_fraction=1.0,
        method="truth",
    )
    return {
        "canonical": to_artifact(GaussianCheckpoint, canonical, step=60),
        "static": static,
        "static_poses": poses,
        "dynamic": to_artifact(CaptureArtifact, tiny_scene.dynamic),
        "registration": registration,
        "masks": to_artifact(MaskSequenceArtifact, true_masks),
        "joints": JointSet(
            joints=[to_artifact(JointParams, j, name=f"joint_{k}") for k, j in enumerate(truth.joints)]
        ),
    }


def test_registration_maps_the_session_poses_onto_the_true_canonical_ones(tiny_scene):
    truth = tiny_scene.truth
    mapped = truth.canonical_from_dynamic_session @ tiny_scene.dynamic.world_from_camera
    # The dynamic capture's own poses are in its session frame; the stage relies on this identity.
    assert np.abs(tiny_scene.dynamic.world_from_camera - truth.dynamic_world_from_camera).max() > 0.01
    np.testing.assert_allclose(mapped, truth.dynamic_world_from_camera, atol=1e-6)


def test_articulate_stage_labels_parts_and_the_report_measures_the_gain(inputs):
    config = ArticulateConfig(holdout_every=3, phase1_steps=12, phase2_steps=4, backend="cpu")
    twin = articulate_twin(config=config, **inputs)
    assert isinstance(twin, GaussianCheckpoint)
    assert twin.step == 60 + 12 + 4
    assert int(np.sum(twin.labels >= LABEL_PART)) > 100
    report = articulate_report(
        canonical=inputs["canonical"], twin=twin, dynamic=inputs["dynamic"], registration=inputs["registration"],
        masks=inputs["masks"], joints=inputs["joints"], config=config,
    )  # fmt: skip
    m = report.metrics
    assert m["heldout_frames_count"] == 4 and len(report.per_frame["psnr_holdout_db"]) == 4
    assert m["part_0_gaussians_count"] > 100
    # Even 16 steps gain over the unmoved model: the door moves on two of the four held-out frames.
    assert m["psnr_gain_db"] > 0.5, m


def test_static_poses_of_another_capture_are_refused(inputs):
    bad = inputs["static_poses"].model_copy(
        update={
            "world_from_camera": inputs["static_poses"].world_from_camera[:2],
            "frame_ids": inputs["static_poses"].frame_ids[:2],
        }
    )
    with pytest.raises(InputError, match="static poses"):
        articulate_twin(
            config=ArticulateConfig(phase1_steps=1, phase2_steps=0), **{**inputs, "static_poses": bad}
        )


def test_the_stage_trains_at_a_lower_resolution_and_is_reported_at_the_captures(inputs):
    """ArticulateConfig.train_max_side (the CPU preset's): both recordings and the masks are
    downscaled together for training (the tiny scene is 128x96, trained at 64x48); the report
    still measures the twin at the capture's resolution."""
    from tasks.articulate import core_config

    config = ArticulateConfig(holdout_every=3, phase1_steps=12, phase2_steps=4, backend="cpu", train_max_side=64)
    assert core_config(config).max_side == 64
    twin = articulate_twin(config=config, **inputs)
    assert twin.step == 60 + 12 + 4 and int(np.sum(twin.labels >= LABEL_PART)) > 100
    report = articulate_report(
        canonical=inputs["canonical"], twin=twin, dynamic=inputs["dynamic"], registration=inputs["registration"],
        masks=inputs["masks"], joints=inputs["joints"], config=config,
    )  # fmt: skip
    assert report.metrics["heldout_frames_count"] == 4
    assert np.isfinite(report.metrics["psnr_holdout_db"]) and report.metrics["psnr_gain_db"] > 0.0, report.metrics
