"""Stage: fit one joint per moving part to the part's 3D point tracks."""

from __future__ import annotations

import numpy as np

from artitwin_core.capture import Capture
from artitwin_core.joints import (
    Joint,
    JointFitConfig,
    StateRefineConfig,
    estimate_joint,
    refine_joint_states,
    to_rgb_clock,
    with_registration_error,
)
from artitwin_core.masks import MaskSequence
from artitwin_core.tracking import Trajectories
from schemas import (
    CaptureArtifact,
    JointConfig,
    JointParams,
    JointSet,
    JointStateConfig,
    MaskSequenceArtifact,
    Registration,
    TrajectoriesArtifact,
)
from tasks._convert import to_artifact, to_core
from tasks._stage import stage


def _fit_config(config: JointConfig) -> JointFitConfig:
    return JointFitConfig(
        ransac_iterations=config.ransac_iterations,
        ransac_threshold_m=config.ransac_threshold_m,
        min_motion_m=config.min_motion_m,
        seed=config.seed,
        # The screw_joint effect enabled: a rotating part is a screw whatever its pitch's significance.
        **(
            {"screw_bic_margin": float("-inf"), "min_screw_travel_m": 0.0, "screw_min_pitch_t": 0.0}
            if config.model_screw
            else {"screw_bic_margin": config.screw_bic_margin}
        ),
    )


def _subset(traj: Trajectories, keep: np.ndarray) -> Trajectories:
    return Trajectories(traj.points_in_world[:, keep], traj.pixels[:, keep], traj.valid[:, keep], traj.query_frame)


@stage(name="fit_joints", version=8, config=JointConfig, output=JointSet)
def fit_joints(trajectories: TrajectoriesArtifact, config: JointConfig) -> JointSet:
    """Fit a joint to each part's tracks; the model-selection scores go in ``selection``."""
    traj = to_core(Trajectories, trajectories)
    part_ids = traj.part_ids if traj.part_ids is not None else np.zeros(traj.valid.shape[1], np.int32)
    joints, selection = [], {}
    for part in np.unique(part_ids):
        fit = estimate_joint(_subset(traj, part_ids == part), _fit_config(config), reference_frame=config.reference_frame)
        name = f"joint_{int(part)}"
        joints.append(to_artifact(JointParams, fit.joint, name=name))
        selection[name] = {f"bic_{h.joint_type}": float(h.bic) for h in fit.hypotheses}
        selection[name]["noise_sigma_m"] = float(fit.noise_sigma_m)
        selection[name]["inlier_tracks_count"] = float(np.count_nonzero(fit.inlier_mask))
    return JointSet(joints=joints, selection=selection)


@stage(name="joint_states", version=8, config=JointStateConfig, output=JointSet)
def refine_states(
    joints: JointSet,
    dynamic: CaptureArtifact,
    masks: MaskSequenceArtifact,
    registration: Registration,
    config: JointStateConfig,
) -> JointSet:
    """Each rotational joint's ``q(t)`` refitted against its part's depth, and a door's line fitted
    to its face planes (``config.refine_line``).

    ``joint_<k>`` moves the part labelled ``k + 1`` in the masks (as ``track_parts`` and
    ``fit_joints`` number them). ``selection`` gains ``state_frames_changed`` per joint: how many
    frames' ``q`` the depth fit replaced. With ``config.rgb_time_offset_s`` (the effect
    ``time_offset``) every joint's states are then moved to its frames' RGB times
    (``to_rgb_clock``).
    """
    capture = to_core(Capture, dynamic)

    def finish(joint: Joint) -> Joint:
        # The registration's error is every joint's: it joins their standard errors.
        if config.rgb_time_offset_s != 0.0:
            joint = to_rgb_clock(joint, capture.timestamps, config.rgb_time_offset_s)
        return with_registration_error(joint, registration.covariance)

    # Where the states were moved to the RGB clock, the set says so (consumers comparing them with
    # depth or tracks lifted from it move them back: ``to_rgb_clock`` with the opposite lag).
    clock = (
        {"rgb_time_offset_s": config.rgb_time_offset_s, "timestamps": np.asarray(capture.timestamps, np.float64)}
        if config.rgb_time_offset_s != 0.0
        else {}
    )
    if not config.refine_from_depth:
        out = [to_artifact(JointParams, finish(to_core(Joint, p)), name=p.name) for p in joints.joints]
        return JointSet(joints=out, selection=joints.selection, **clock)
    seq = to_core(MaskSequence, masks)
    labels = {int(v) for v in np.unique(seq.part) if v > 0}
    out, selection = [], {name: dict(scores) for name, scores in joints.selection.items()}
    for params in joints.joints:
        joint = to_core(Joint, params)
        label = int(params.name.rsplit("_", 1)[-1]) + 1
        if label in labels:
            refined = refine_joint_states(
                joint, capture, seq, label, registration.canonical_from_session,
                StateRefineConfig(max_points=config.max_points, refine_axis=config.refine_line),
            )  # fmt: skip
            changed = int(np.count_nonzero(np.abs(np.asarray(refined.q) - np.asarray(joint.q)) > 1e-9))
            joint = refined
        else:
            changed = 0
        out.append(to_artifact(JointParams, finish(joint), name=params.name))
        selection.setdefault(params.name, {})["state_frames_changed"] = float(changed)
    return JointSet(joints=out, selection=selection, **clock)
