"""Part and hand masks of every dynamic frame (``segment_parts``): find the parts that moved,
fit their motion, and label them in every frame.

The vanished surfaces are screened into parts at the reference frame
(``segment_part_at_frame``). Going backwards from the last frame, each frame's joint state is
searched near the next frame's, so the part closes smoothly in the labels
(``propagate_masks_backwards``).
"""

from __future__ import annotations

from dataclasses import dataclass, replace

import cv2
import numpy as np
from scipy.spatial import cKDTree

from artitwin_core._errors import InputError
from artitwin_core.capture import Capture
from artitwin_core.change._canonical import CanonicalMesh
from artitwin_core.change._config import PartConfig
from artitwin_core.change._grow import _grow_over_frames
from artitwin_core.change._label import (
    _static_depth_without_parts,
    label_frame,
    part_triangles,
    sample_normals,
)
from artitwin_core.change._motion import (
    _fit_setup,
    _fit_slide_and_grow,
    _fit_ungrown,
    _reference_support,
    _same_joint,
)
from artitwin_core.change._score import _best_state, _scoring_subset, in_place, motion_score
from artitwin_core.change._vanish import find_moved_parts
from artitwin_core.change._views import FrameView, PartModel, frame_views
from artitwin_core.joints import Joint
from artitwin_core.masks import MaskSequence
from artitwin_core.parts import PartFate


@dataclass(frozen=True)
class PartSegmentation:
    """What ``segment_parts`` found.

    Attributes:
        masks: per-frame part labels, hand masks and scores (RGB resolution).
        models: the moving parts, in onset order (label k + 1 is ``models[k]``).
        states: ``[T, K]`` joint state of each part per frame (radians or metres).
        candidates: ``[K]`` the candidate index (:func:`find_moved_parts` order) of each part.
        fates: the candidates that are not a part of their own, and why (:func:`screen_candidates`).
    """

    masks: MaskSequence
    models: list[PartModel]
    states: np.ndarray
    candidates: np.ndarray | None = None
    fates: tuple[PartFate, ...] = ()

    def joints(self) -> list[Joint]:
        """Each part's joint as the part finder fitted it to the change in depth (label k + 1 is
        ``joints()[k]``): its type, axis and pivot, and its state in every frame as the masks
        were propagated (confidence 0.5: measured, not vouched for; no track residuals). A second
        opinion beside the joint fitted to the part's tracks."""
        out = []
        for k, m in enumerate(self.models):
            q = np.asarray(self.states[:, k], dtype=np.float64)
            out.append(Joint(joint_type=m.joint_type, axis=np.asarray(m.axis, np.float64), pivot=np.asarray(m.pivot, np.float64),
                             q=q, q_range=np.array([q.min(), q.max()]), residual=np.full(len(q), np.nan),
                             confidence=np.full(len(q), 0.5)))
        return out


def segment_part_at_frame(
    views: list[FrameView],
    frame: int | None = None,
    *,
    gravity=(0.0, -1.0, 0.0),
    mesh: CanonicalMesh | None = None,
    config: PartConfig | None = None,
) -> list[PartModel]:
    """Find the moved parts and fit each one's motion at ``frame`` (default: the last frame).

    The changed region at that frame is explained by rigid part motions only; what is in front
    of the moved parts and the static scene (hand, arm) is not part.

    Args:
        views: every dynamic frame (:func:`frame_views`), canonical frame.
        frame: the reference frame.
        gravity: ``[3]`` gravity direction in the canonical frame.
        mesh: the canonical mesh (optional; sharper part extents).

    Returns:
        the parts in onset order; empty when nothing moved (:func:`screen_candidates` also says
        what became of the candidates that are not among them).
    """
    return screen_candidates(views, frame, gravity=gravity, mesh=mesh, config=config)[0]


def screen_candidates(
    views: list[FrameView],
    frame: int | None = None,
    *,
    gravity=(0.0, -1.0, 0.0),
    mesh: CanonicalMesh | None = None,
    config: PartConfig | None = None,
) -> tuple[list[PartModel], list[int], list[PartFate]]:
    """:func:`segment_part_at_frame`, with every candidate accounted for.

    Each vanished surface (:func:`find_moved_parts`, candidates numbered in its order) is fitted;
    one that touches a part kept before it and moves with that part (the same joint, or that
    part's motion explains what its reference frame sees of it) is merged into it: a door's strip
    along its hinge vanishes later than the rest of it and is clustered apart. One that no motion
    explains (too little of it supported at its fitted state) is dropped.

    When no vanished surface is kept, the surfaces hidden by something nearer
    (``find_moved_parts(..., hidden=True)``, numbered after the vanished ones) are screened the
    same way: a drawer pulled straight at a close-up camera leaves no vanished surface of its
    own, and a sliver of vanished surface elsewhere (a carcass edge seen at a grazing angle,
    where a millimetre of pose error looks like change) must not hide it. Only when none is
    kept: a part that vanished is seen better by what vanished. (:func:`segment_parts` then
    screens the hidden surface its parts' labels do not explain, for a drawer beside a door.)

    Returns:
        the kept parts, the candidate index of each, and the fates of the others.
    """
    cfg = config or PartConfig()
    vanished = find_moved_parts(views, cfg)
    models, kept, fates = _screen(vanished, 0, views, frame, gravity, mesh, cfg, hidden=False)
    if not models:
        hidden = find_moved_parts(views, cfg, hidden=True, mesh=mesh)
        models, kept, more = _screen(hidden, len(vanished), views, frame, gravity, mesh, cfg, hidden=True)
        fates += more
    return models, kept, fates


def _screen(
    candidates: list[tuple[np.ndarray, int]], first: int, views: list[FrameView], frame: int | None, gravity,
    mesh: CanonicalMesh | None, cfg: PartConfig, hidden: bool, earlier: list[PartModel] = (),
) -> tuple[list[PartModel], list[int], list[PartFate]]:
    """:func:`screen_candidates` over ``candidates`` (closed samples and onset each), numbered
    from ``first``; ``hidden``: they are surfaces hidden by something nearer, and only the
    samples a fit moves onto observed change count as its support (``still_supports=False`` in
    :func:`motion_score`): the static scene around what the hand hid supports any small motion.
    A candidate that one of the ``earlier`` parts hosts is dropped."""
    models: list[PartModel] = []
    kept: list[int] = []
    fates: list[PartFate] = []
    for i, (pts, onset) in enumerate(candidates, start=first):
        up, frames = _fit_setup(pts, views, gravity, frame, cfg, hidden)
        # Hidden surface is the part's front, moved back from where it was seen nearer, facing
        # the closed surface's way (``hidden_parallel_deg``): only a slide does that, so no
        # swing is tried. The front's rim, moved out, floats in front of the scene, which it
        # does not contradict; so no see-through penalty in its fit.
        fit_cfg = replace(cfg, violation_weight=0.0, max_rotation_rad=0.0) if hidden else cfg
        model = replace(_fit_ungrown(pts, onset, views, up, frames, fit_cfg, mesh, still_supports=not hidden), hidden=hidden)
        tilt = float(np.degrees(np.arcsin(min(1.0, abs(float(model.axis @ up))))))
        if hidden and tilt > cfg.hidden_max_tilt_deg:
            # A drawer slides level. Something held over a floor, a shelf or a worktop (a boxy
            # glove's flat top) hides a surface that faces its way too, and "slides" up from it.
            fates.append(PartFate(candidate=i, fate="dropped", stage="part_masks",
                                  reason=f"its {len(pts)} surface samples, hidden by a nearer surface facing their way, "
                                  f"would slide {tilt:.0f} deg from level (drawers slide level; at most "
                                  f"{cfg.hidden_max_tilt_deg:g} deg)"))
            continue
        host = _host_part(model, [*earlier, *models], views, cfg)
        if host is not None and host[0] < len(earlier):
            fates.append(PartFate(candidate=i, fate="dropped", stage="part_masks",
                                  reason=f"hidden where part {host[0]} moved: {host[1]}"))
            continue
        if host is not None:
            k, why = host[0] - len(earlier), host[1]
            models[k] = replace(models[k], closed_points=np.concatenate([models[k].closed_points, model.closed_points]))
            fates.append(PartFate(candidate=i, fate="merged", stage="part_masks", into=kept[k], reason=why))
            continue
        support = _reference_support(model, views[model.reference_frame], cfg, still_supports=not hidden)
        if support < cfg.min_part_support:
            # No motion of this surface explains what the reference frame sees: it vanished for
            # another reason (a cabinet side seen edge-on can vanish from the first frame on and
            # would come out as a second part with no support at all).
            fates.append(PartFate(
                candidate=i, fate="dropped", stage="part_masks",
                reason=f"no motion of its {len(model.closed_points)} surface samples explains what frame "
                f"{model.reference_frame} sees ({support} supported at its best fit; {cfg.min_part_support} needed)",
            ))
            continue
        models.append(_fit_slide_and_grow(model, views, cfg, mesh))
        kept.append(i)
    return models, kept, fates


def _host_part(
    model: PartModel, kept: list[PartModel], views: list[FrameView], cfg: PartConfig
) -> tuple[int, str] | None:
    """The kept part ``model``'s surface belongs to, with the reason, or None.

    It must touch that part (closed samples within ``host_reach_m``) and move with it: the same
    joint (``_same_joint``), or that part's motion at its reference state explains most of what
    the reference frame sees of ``model``'s samples (supported, not seen through, and better than
    the samples held still)."""
    sub = _scoring_subset(model.closed_points)
    for k, host in enumerate(kept):
        gap = float(cKDTree(host.closed_points).query(sub, distance_upper_bound=cfg.host_reach_m)[0].min())
        if not np.isfinite(gap):
            continue
        if _same_joint(model, host):
            return k, f"it touches candidate part {k}'s surface ({1e3 * gap:.0f} mm) and was fitted with the same joint"
        view = views[host.reference_frame]
        m = host.motion(host.reference_q)
        score, support, through = motion_score(view, sub @ m[:3, :3].T + m[:3, 3], sub, cfg)
        still, _, _ = motion_score(view, sub, sub, cfg)
        if support >= cfg.host_min_support_frac * len(sub) and score > max(still, 0.0):
            return k, (f"it touches candidate part {k}'s surface ({1e3 * gap:.0f} mm) and that part's motion explains "
                       f"{support} of its {len(sub)} samples in frame {host.reference_frame} ({through} seen through)")
    return None


def propagate_masks_backwards(
    models: list[PartModel],
    views: list[FrameView],
    dynamic: Capture,
    mesh: CanonicalMesh,
    config: PartConfig | None = None,
) -> PartSegmentation:
    """Label every frame, from the reference frame (normally the last) back to the first,
    tracking each part's joint state.

    Each frame's state is searched near the following frame's (within ``search_window`` of the
    reference state, and closed), so the labels follow the part as it closes. Frames after a
    reference frame that is not the last are tracked forwards the same way.

    Args:
        models: the parts (:func:`segment_part_at_frame`), fitted at the last frame.
        views: every dynamic frame (:func:`frame_views`).
        dynamic: the dynamic recording (RGB frames, size and intrinsics).
        mesh: the canonical mesh (for what the parts hide or reveal).
    """
    cfg = config or PartConfig()
    n = len(views)
    if n != dynamic.num_frames:
        raise InputError(f"propagate_masks_backwards: {n} views for a recording of {dynamic.num_frames} frames.")
    tris = part_triangles(mesh, models, radius_m=1.5 * cfg.vanish_voxel_m)
    states = np.zeros((n, len(models)))
    scores = np.zeros((n, len(models)))
    for k, model in enumerate(models):
        r = min(model.reference_frame, n - 1)
        order = list(range(r, -1, -1)) + list(range(r + 1, n))
        current = model.reference_q
        # A drawer's samples that its reference frame still sees in place are static surface
        # (a door's stay: on its hinge side they are the door, seen in place at any angle).
        static = in_place(model, views[r], cfg) if model.joint_type == "prismatic" else None
        # A hidden surface's rim is seen through once moved out (see PartModel.hidden): no
        # see-through penalty in its state search either, or the closed state wins near the camera.
        state_cfg = replace(cfg, violation_weight=0.0) if model.hidden else cfg
        for t in order:
            if t == r + 1:
                current = states[r, k]  # forwards again from the reference state
            current, scores[t, k] = _best_state(model, views[t], current, state_cfg, after_reference=t > r, static=static)
            states[t, k] = current
    if cfg.grow_frames > 0:
        models = [_grow_over_frames(model, views, states[:, k], scores[:, k], mesh, cfg)
                  for k, model in enumerate(models)]
    part, hand = _label_frames(models, states, views, dynamic, mesh, tris, cfg)
    score = scores.min(1) if len(models) else np.zeros(n)
    return PartSegmentation(MaskSequence(part, hand, score.astype(np.float32)), models, states)


def _label_frames(
    models: list[PartModel], states: np.ndarray, views: list[FrameView], dynamic: Capture, mesh: CanonicalMesh,
    tris: np.ndarray, cfg: PartConfig,
) -> tuple[np.ndarray, np.ndarray]:
    """Part labels ``[T, H, W]`` uint8 and hand masks ``[T, H, W]`` bool of every frame at the
    parts' states ``states [T, K]``; ``tris`` are the canonical triangles on the parts."""
    width, height = dynamic.rgb_size
    n = len(views)
    part = np.zeros((n, height, width), np.uint8)
    hand = np.zeros((n, height, width), bool)
    normals = [sample_normals(m.closed_points) for m in models]
    for t in range(n):
        static_d = _static_depth_without_parts(mesh, tris, views[t].world_from_camera, dynamic.rgb_intrinsics[t],
                                               width, height)
        part[t], hand[t] = label_frame(models, list(states[t]), views[t].world_from_camera,
                                       dynamic.rgb_intrinsics[t], (width, height), views[t].observed_depth,
                                       static_d, cfg, normals, observed_rgb=dynamic.rgb[t])
    return part, hand


def segment_parts(
    dynamic: Capture,
    canonical_from_session: np.ndarray,
    mesh: CanonicalMesh,
    *,
    gravity=(0.0, -1.0, 0.0),
    config: PartConfig | None = None,
) -> PartSegmentation:
    """Part and hand masks for every dynamic frame, with the default geometric backend.

    Args:
        dynamic: the dynamic recording (its own session frame).
        canonical_from_session: ``[4, 4]`` from :func:`register_recordings`.
        mesh: the canonical model (:func:`build_canonical_tsdf`).
        gravity: ``[3]`` gravity direction in the canonical frame.
    """
    cfg = config or PartConfig()
    views = frame_views(dynamic, np.asarray(canonical_from_session, dtype=np.float64), mesh)
    models, kept, fates = screen_candidates(views, None, gravity=gravity, mesh=mesh, config=cfg)
    first = max([*kept, *(f.candidate for f in fates)], default=-1) + 1
    if len(models) > 1 and models[0].hidden:
        # A front pulled out hides more than its own closed place: behind it, a wall facing its
        # way, which a second hidden "part" slides out of. Only the first is kept here; the
        # look below, outside its labels, sees what the others are.
        later = set(kept[1:])
        fates = [replace(f, fate="dropped", into=None, reason=f"merged into candidate {f.into}, itself dropped below")
                 if f.fate == "merged" and f.into in later else f for f in fates]
        fates += [PartFate(candidate=k, fate="dropped", stage="part_masks",
                           reason=f"hidden surface found after candidate {kept[0]}'s: looked at again where that part's "
                           f"labels do not explain it (candidates from {first} on)") for k in kept[1:]]
        models, kept = models[:1], kept[:1]
    seg = propagate_masks_backwards(models, views, dynamic, mesh, cfg)
    if models and cfg.min_occluded_frames > 0:
        # A drawer pulled straight at the camera hides its front and leaves nothing vanished,
        # whatever else vanished beside it (a door above it): what the parts found do not
        # explain of the hidden surface is screened too.
        more, more_kept, more_fates = _screen_unexplained_hidden(seg, views, first, gravity, mesh, cfg)
        fates += more_fates
        if more:
            models, kept = models + more, kept + more_kept
            seg = propagate_masks_backwards(models, views, dynamic, mesh, cfg)
    return replace(seg, candidates=np.asarray(kept, dtype=np.int32), fates=tuple(fates))


def _screen_unexplained_hidden(
    seg: PartSegmentation, views: list[FrameView], first: int, gravity, mesh: CanonicalMesh, cfg: PartConfig
) -> tuple[list[PartModel], list[int], list[PartFate]]:
    """:func:`screen_candidates` for the surfaces hidden by something nearer where no part of
    ``seg`` is seen (its labels, grown by a pixel), candidates numbered from ``first``. One that
    a part of ``seg`` hosts (:func:`_host_part`) is dropped, not merged: that part's surface
    was found as it vanished, and what it hid beside its labels (a door turned a little, facing
    almost the way it did closed) would only blur it."""
    h, w = views[0].observed_depth.shape
    kernel = np.ones((3, 3), np.uint8)
    explained = [
        cv2.resize(cv2.dilate((np.asarray(p) > 0).astype(np.uint8), kernel), (w, h), interpolation=cv2.INTER_AREA) > 0
        for p in seg.masks.part
    ]
    hidden = find_moved_parts(views, cfg, hidden=True, explained=explained, mesh=mesh)
    return _screen(hidden, first, views, None, gravity, mesh, cfg, hidden=True, earlier=seg.models)
