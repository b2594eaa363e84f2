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
from artitwin_core.parts import prefer_depth_joint, uncertain_joint
from artitwin_core.tracking import Trajectories
from schemas import (
    CaptureArtifact,
    JointConfig,
    JointParams,
    JointSet,
    JointStateConfig,
    MaskSequenceArtifact,
    PartFateArtifact,
    Registration,
    TrajectoriesArtifact,
)
from tasks._convert import config_map, core_kwargs, to_artifact, to_core, to_core_config
from tasks._stage import stage

config_map(
    JointConfig,
    {
        JointFitConfig: "ransac_iterations ransac_threshold_m min_motion_m screw_bic_margin seed",
        estimate_joint: "reference_frame",
    },
    stage_only={
        "model_screw": "the effect screw_joint: sets JointFitConfig's screw_bic_margin, min_screw_travel_m and "
        "screw_min_pitch_t together, so that every rotating part is a screw",
        "screw_joints": "the effect joint_N:screw_joint: model_screw's settings for the joints it names only",
    },
)
config_map(
    JointStateConfig,
    {StateRefineConfig: {"max_points": "max_points", "refine_line": "refine_axis"}},
    stage_only={
        "refine_from_depth": "off: the stage keeps the tracks' states and runs no StateRefineConfig at all",
        "rgb_time_offset_s": "the effect time_offset: the value to_rgb_clock takes (it has no default)",
        "second_opinion": "off: prefer_depth_joint is not asked",
        "unsure_axis_se_deg": "prefer_depth_joint's max_axis_se_rad, in degrees",
        "unsure_pivot_se_m": "prefer_depth_joint's max_pivot_se_m",
    },
)

# The screw_joint effect enabled: a rotating part is a screw whatever its pitch's significance.
_SCREW_ALWAYS = {"screw_bic_margin": float("-inf"), "min_screw_travel_m": 0.0, "screw_min_pitch_t": 0.0}


def _fit_config(config: JointConfig, name: str) -> JointFitConfig:
    """The fit of joint ``name``: a screw whatever its pitch's significance where the effect
    screw_joint names it, or names no joint (then every rotating part)."""
    screw = config.model_screw or name in config.screw_joints
    return to_core_config(JointFitConfig, config, **(_SCREW_ALWAYS if screw else {}))


def _subset(traj: Trajectories, keep: np.ndarray) -> Trajectories:
    return Trajectories(traj.points_in_world[:, keep], traj.pixels[:, keep], traj.valid[:, keep], traj.query_frame)


@stage(name="fit_joints", version=11, config=JointConfig, output=JointSet)
def fit_joints(trajectories: TrajectoriesArtifact, masks: MaskSequenceArtifact, config: JointConfig) -> JointSet:
    """Fit a joint to each candidate part's tracks; the model-selection scores go in ``selection``.

    ``joint_<k>`` is fitted to the tracks of mask label ``k + 1`` (``mask_labels``). A candidate
    with no tracks, or whose fit fails, gets no joint but a fate saying why (``settle_parts``
    decides whether it merges into a neighbour or is dropped); the other candidates are fitted
    all the same."""
    traj = to_core(Trajectories, trajectories)
    part_ids = traj.part_ids if traj.part_ids is not None else np.zeros(traj.valid.shape[1], np.int32)
    labels = [int(v) for v in np.unique(masks.part) if v > 0]
    joints, selection, fitted, fates = [], {}, [], []
    for label in labels:
        keep = part_ids == label - 1
        n_tracks = int(np.count_nonzero(traj.valid[:, keep].any(0)))
        name = f"joint_{label - 1}"
        try:
            fit = estimate_joint(_subset(traj, keep), _fit_config(config, name), **core_kwargs(estimate_joint, config))
        except Exception as e:  # noqa: BLE001 (one candidate's failure is its own: it is reported, the others go on)
            why = "no point could be tracked on it" if n_tracks == 0 else f"no joint could be fitted to its {n_tracks} tracks ({e})"
            fates.append(PartFateArtifact(candidate=candidate_index(masks, label), fate="dropped", stage="fit_joints",
                                          reason=why, label=label))
            continue
        joints.append(to_artifact(JointParams, fit.joint, name=name))
        fitted.append(label)
        selection[name] = {f"bic_{h.joint_type}": float(h.bic) for h in fit.hypotheses}
        selection[name]["noise_sigma_m"] = float(fit.noise_sigma_m)
        selection[name]["inlier_tracks_count"] = float(np.count_nonzero(fit.inlier_mask))
        selection[name]["tracks_count"] = float(n_tracks)
        if config.model_screw or name in config.screw_joints:
            selection[name]["screw_effect"] = 1.0  # asked for: settle_parts leaves the screw a screw
    return JointSet(joints=joints, selection=selection, mask_labels=fitted, fates=fates)


def _second_opinion(
    joint: Joint, depth: JointParams, capture: Capture, masks: MaskSequence, label: int, registration: Registration,
    config: JointStateConfig,
) -> tuple[Joint, str, bool]:
    """``joint`` (the tracks', states refined) or, where it is unsure and the part finder's
    ``depth`` joint explains the part's depth better, that one with its states refined too; a
    note saying which and why (empty where the tracks' joint is sure), and whether it changed."""
    unsure = {"max_axis_se_rad": float(np.radians(config.unsure_axis_se_deg)), "max_pivot_se_m": config.unsure_pivot_se_m}
    if not uncertain_joint(joint, **unsure):  # before refining the alternative, which costs seconds
        return joint, "", False
    c_from_s = registration.canonical_from_session
    try:
        alternative = refine_joint_states(to_core(Joint, depth), capture, masks, label, c_from_s,
                                          to_core_config(StateRefineConfig, config))
        use, why = prefer_depth_joint(joint, alternative, capture, masks, label, c_from_s, **unsure)
    except Exception as e:  # noqa: BLE001 (the tracks' joint stands; the note says why)
        return joint, f"the part finder's joint could not be compared ({type(e).__name__}: {e})", False
    return (alternative if use else joint), why, use


def candidate_index(masks: MaskSequenceArtifact, label: int) -> int:
    """The part finder's candidate index of mask ``label``."""
    return int(masks.candidates[label - 1]) if masks.candidates is not None else label - 1


@stage(name="joint_states", version=14, config=JointStateConfig, output=JointSet)
def refine_states(
    joints: JointSet,
    dynamic: CaptureArtifact,
    masks: MaskSequenceArtifact,
    registration: Registration,
    config: JointStateConfig,
) -> JointSet:
    """Each joint's ``q(t)`` refitted against its part's depth (a drawer's too), and a door's line fitted
    to its face planes (``config.refine_line``).

    ``joints`` and ``masks`` are the settled ones (``settle_parts``, ``final_masks``): joint ``k``
    moves the part labelled ``k + 1``. ``selection`` gains ``state_frames_changed`` per joint: how
    many frames' ``q`` the depth fit replaced. A joint whose refinement fails keeps its tracks'
    states, with a note; the others are refined all the same. Where a joint's own standard errors
    say the tracks left it unsure, the part finder's joint (``masks.depth_joints``) is refined too
    and replaces it if it explains the part's depth better (``config.second_opinion``;
    ``selection``'s ``joint_from_depth`` and a note say so). With ``config.rgb_time_offset_s``
    (the effect ``time_offset``) every joint's states are then moved to its frames' RGB times
    (``to_rgb_clock``).
    """
    capture = to_core(Capture, dynamic)

    def finish(joint: Joint) -> Joint:
        # The registration's error is every joint's: it joins their standard errors.
        return with_registration_error(joint, registration.covariance)

    def clocked(states: JointSet) -> JointSet:
        # With the effect time_offset the states move to the RGB clock; the set says so and keeps
        # them as measured, on the depth maps' clock (consumers comparing them with depth or tracks
        # lifted from it read those: moved there and back, interpolated twice between frames, they
        # are not the same).
        if config.rgb_time_offset_s == 0.0:
            return states
        ts = np.asarray(capture.timestamps, np.float64)
        moved = [to_artifact(JointParams, to_rgb_clock(to_core(Joint, p), ts, config.rgb_time_offset_s), name=p.name)
                 for p in states.joints]
        measured = np.stack([np.asarray(p.q, np.float64) for p in states.joints]) if states.joints else None
        return JointSet(**{**dict(states), "joints": moved, "rgb_time_offset_s": config.rgb_time_offset_s,
                           "timestamps": ts, "depth_clock_q": measured})

    settled = {"mask_labels": joints.mask_labels, "label_map": joints.label_map, "fates": joints.fates}
    if not config.refine_from_depth:
        out = [to_artifact(JointParams, finish(to_core(Joint, p)), name=p.name) for p in joints.joints]
        return clocked(JointSet(joints=out, selection=joints.selection, **settled))
    seq = to_core(MaskSequence, masks)
    labels = {int(v) for v in np.unique(seq.part) if v > 0}
    out, notes = [], []
    selection = {name: dict(scores) for name, scores in joints.selection.items()}
    for k, params in enumerate(joints.joints):
        joint = to_core(Joint, params)
        changed = 0
        if k + 1 in labels:
            try:
                refined = refine_joint_states(
                    joint, capture, seq, k + 1, registration.canonical_from_session,
                    to_core_config(StateRefineConfig, config),
                )  # fmt: skip
            except Exception as e:  # noqa: BLE001 (this joint keeps its tracks' states; the others go on)
                notes.append(f"{params.name}: the states could not be refined from depth ({type(e).__name__}: {e}); "
                             "they are the tracks' states.")
            else:
                changed = int(np.count_nonzero(np.abs(np.asarray(refined.q) - np.asarray(joint.q)) > 1e-9))
                joint = refined
            if config.second_opinion and k < len(masks.depth_joints):
                joint, note, swapped = _second_opinion(joint, masks.depth_joints[k], capture, seq, k + 1, registration, config)
                if note:
                    notes.append(f"{params.name}: {note}.")
                sel = selection.setdefault(params.name, {})
                sel["joint_from_depth"] = float(swapped or sel.get("joint_from_depth", 0.0) > 0)  # or settle_parts' stand-in
        out.append(to_artifact(JointParams, finish(joint), name=params.name))
        selection.setdefault(params.name, {})["state_frames_changed"] = float(changed)
    return clocked(JointSet(joints=out, selection=selection, notes=notes, **settled))
