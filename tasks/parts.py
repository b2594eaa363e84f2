"""Stages: settle which candidate parts are parts, and relabel the masks to the settled parts.

``settle_parts`` runs after ``fit_joints``: every candidate the part finder labelled is kept,
merged into the part whose motion explains it, or dropped with the reason
(``artitwin_core.parts.settle_parts``), and the kept ones are numbered again (joint ``k``).
``final_masks`` applies that to the masks (label ``k + 1``). Every later stage reads these two,
so masks, joints, the twin and the export agree on one set of parts, and a spurious candidate is
never exported.
"""

from __future__ import annotations

import numpy as np

from artitwin_core.capture import Capture
from artitwin_core.joints import Joint
from artitwin_core.masks import MaskSequence
from artitwin_core.parts import PartFate, SettleConfig, relabel, settle_parts
from schemas import (
    CaptureArtifact,
    JointParams,
    JointSet,
    MaskSequenceArtifact,
    PartFateArtifact,
    Registration,
    SettlePartsConfig,
    TrajectoriesArtifact,
)
from tasks._convert import config_map, to_artifact, to_core, to_core_config
from tasks._stage import stage

config_map(SettlePartsConfig, {SettleConfig: " ".join(SettlePartsConfig.model_fields)})  # every field, by its name


@stage(name="settle_parts", version=6, config=SettlePartsConfig, output=JointSet)
def settle_candidate_parts(
    joints: JointSet,
    trajectories: TrajectoriesArtifact,
    masks: MaskSequenceArtifact,
    dynamic: CaptureArtifact,
    registration: Registration,
    config: SettlePartsConfig,
) -> JointSet:
    """The settled parts: one joint per kept candidate, numbered again in the candidates' order
    (``joint_k``; ``mask_labels`` says which candidate label it was, ``label_map`` where every
    candidate label goes), with every candidate's fate (``fates``): the part finder's, the joint
    fit's and this stage's. A part whose tracks gave no joint, a fixed one, one that hardly moves or
    one its depth refutes, but whose depth confirms the part finder's joint (``masks.depth_joints``), is kept on that joint
    (``selection``'s ``joint_from_depth`` is 1 and its fate says why)."""
    labels = joints.mask_labels if joints.mask_labels is not None else list(range(1, len(joints.joints) + 1))
    candidate_joints = {lab: to_core(Joint, j) for lab, j in zip(labels, joints.joints, strict=True)}
    part_ids = trajectories.part_ids if trajectories.part_ids is not None else np.zeros(trajectories.valid.shape[1], np.int32)
    seen = trajectories.valid.any(0)
    tracks = {int(p) + 1: int(np.count_nonzero(seen & (part_ids == p))) for p in np.unique(part_ids)}
    earlier = [to_core(PartFate, f) for f in list(masks.fates) + list(joints.fates)]
    depth_joints = {lab: to_core(Joint, j) for lab, j in enumerate(masks.depth_joints, start=1)}
    asked = {lab for lab, j in zip(labels, joints.joints, strict=True) if joints.selection.get(j.name, {}).get("screw_effect")}
    decision = settle_parts(
        to_core(Capture, dynamic), to_core(MaskSequence, masks), registration.canonical_from_session, candidate_joints,
        candidates=masks.candidates, tracks=tracks, earlier=earlier, depth_joints=depth_joints, screws_asked=asked,
        config=to_core_config(SettleConfig, config),
    )  # fmt: skip
    by_label = dict(zip(labels, joints.joints, strict=True))
    kept, selection = [], {}
    for k, lab in enumerate(decision.kept_labels):
        name = f"joint_{k}"
        # The part finder's joint standing in, a screw its depth reduced, or the tracks' joint.
        replaced = decision.replaced.get(lab)
        kept.append(to_artifact(JointParams, replaced, name=name) if replaced is not None
                    else by_label[lab].model_copy(update={"name": name}))
        selection[name] = ({"joint_from_depth": 1.0} if lab in decision.from_depth
                           else dict(joints.selection.get(by_label[lab].name, {})))
    return JointSet(
        joints=kept,
        selection=selection,
        mask_labels=list(decision.kept_labels),
        label_map=decision.label_map.astype(np.int32),
        fates=[to_artifact(PartFateArtifact, f) for f in decision.fates],
    )


@stage(name="final_masks", version=2, config=SettlePartsConfig, output=MaskSequenceArtifact)
def final_masks(masks: MaskSequenceArtifact, parts: JointSet, config: SettlePartsConfig) -> MaskSequenceArtifact:
    """The masks with the settled parts' labels (``k + 1`` = joint ``k``; merged candidates take
    their part's label, dropped ones none), every candidate's fate, and each settled part's
    depth-fitted joint (``depth_joints[k]`` for joint ``k``, where the part finder recorded them)."""
    part = masks.part if parts.label_map is None else relabel(masks.part, parts.label_map)
    labels = parts.mask_labels if parts.mask_labels is not None else list(range(1, len(parts.joints) + 1))
    depth = [masks.depth_joints[lab - 1].model_copy(update={"name": f"joint_{k}"}) for k, lab in enumerate(labels)] \
        if len(masks.depth_joints) >= max(labels, default=0) else []
    return MaskSequenceArtifact(part=part, hand=masks.hand, score=masks.score, fates=list(parts.fates), depth_joints=depth)
