"""Overlap-aware evidence for a registration hypothesis, from what the static recording saw.

Under a hypothesis, each dynamic point falls in one of three places of the static recording's
world: on a surface it measured (evidence for), in space its depth rays passed through (free
space: evidence against, since something would have blocked them), or somewhere it never
observed (outside its views, or behind what it saw: no evidence either way). Counting inliers
over all dynamic points instead punishes the right answer wherever the two recordings do not
overlap, and rewards a wrong one that squeezes the dynamic cloud onto whatever surfaces are near.
The same test runs the other way round for the static points: a dynamic depth ray that passed
through a static surface also counts against, and so does a dynamic point on a static surface
seen from its other side (the static cameras saw it from one side; an opaque surface is not seen
through from behind).

The moved part (and the hand) legitimately sit in space the static recording saw empty, but only
once the part has moved, so the dynamic frames are scored one by one and the early ones (part
most likely still closed) weigh more; a wrong placement conflicts in the early frames too.

Geometry cannot tell apart surfaces of the same shape (two corners of a box-shaped room), so
each hypothesis also gets the agreement of the texture on its matched surfaces
(:mod:`._texture`).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import open3d as o3d
from scipy import ndimage

from artitwin_core.capture import Capture
from artitwin_core.geometry import nearest_pixel, project
from artitwin_core.registration._gravity_icp import PlaneTarget
from artitwin_core.registration._texture import within_surface_correlation
from artitwin_core.registration._types import HypothesisScore


@dataclass(frozen=True)
class DepthViews:
    """Depth maps of a subset of a recording's frames, for free-space tests.

    Attributes:
        camera_from_world: ``[K, 4, 4]`` world-to-camera transforms (OpenCV axes).
        intrinsics: ``[K, 4]`` ``(fx, fy, cx, cy)`` at the stored (strided) depth resolution.
        near_depth: ``[K, h, w]`` metres: the nearest depth within one pixel (NaN = no
            measurement or beyond the depth limit), so a point beside a depth edge is never free.
    """

    camera_from_world: np.ndarray
    intrinsics: np.ndarray
    near_depth: np.ndarray


def evenly_spaced(num_frames: int, count: int) -> np.ndarray:
    """``[K]`` sorted frame indices, at most ``count`` of ``num_frames``, first and last included."""
    return np.unique(np.linspace(0, num_frames - 1, max(1, min(count, num_frames))).round().astype(np.int64))


def depth_views(capture: Capture, num_views: int, *, stride: int, max_depth_m: float, min_confidence: int,
                farthest: bool = False) -> DepthViews:
    """Up to ``num_views`` evenly spaced frames of ``capture``, depth subsampled by ``stride``,
    each pixel the nearest depth of its 3x3 neighbourhood (what a ray surely passed through);
    with ``farthest``, the farthest (what surely hides nothing nearer: for visibility)."""
    frames = evenly_spaced(capture.num_frames, num_views)
    depth = capture.depth[frames][:, ::stride, ::stride].astype(np.float32, copy=True)
    depth[~(depth < max_depth_m)] = np.nan
    if capture.confidence is not None and min_confidence > 0:
        depth[capture.confidence[frames][:, ::stride, ::stride] < min_confidence] = np.nan
    if farthest:
        near = ndimage.maximum_filter(np.where(np.isfinite(depth), depth, -np.inf), size=(1, 3, 3))
    else:
        near = ndimage.minimum_filter(np.where(np.isfinite(depth), depth, np.inf), size=(1, 3, 3))
    near[~np.isfinite(near)] = np.nan
    fx, fy, cx, cy = capture.depth_intrinsics[frames].T
    # Pixel (u, v) of the strided map is pixel (u * s, v * s) of the full one.
    intr = np.stack([fx / stride, fy / stride, cx / stride, cy / stride], -1)
    return DepthViews(np.linalg.inv(capture.world_from_camera[frames]), intr, near.astype(np.float32))


@dataclass(frozen=True)
class Evidence:
    """How one recording's points sit in the other recording's world under one hypothesis.

    Attributes:
        agree: points on the other recording's surface (within the inlier distance), seen from
            the side it was seen from.
        conflict: points in space the other recording saw through (free space), or on one of
            its surfaces seen from behind.
        total: points tested.
        agree_mask: ``[N]`` bool, which points agree.
        matched: ``[N]`` index of each point's nearest surface point in the target (meaningful
            where ``agree_mask``).
    """

    agree: int
    conflict: int
    total: int
    agree_mask: np.ndarray
    matched: np.ndarray

    @property
    def overlap(self) -> float:
        """Fraction of the points that fall where the other recording looked."""
        return (self.agree + self.conflict) / max(self.total, 1)

    @property
    def inlier_ratio(self) -> float:
        """Of the points where the other recording looked, the fraction on its surfaces."""
        return self.agree / max(self.agree + self.conflict, 1)

    @property
    def support(self) -> float:
        """Evidence for minus evidence against, per point tested."""
        return (self.agree - self.conflict) / max(self.total, 1)


def _project(points: np.ndarray, views: DepthViews, i: int, near_m: float):
    """Pixel ``u, v``, depth ``z`` of ``points [N, 3]`` in view ``i``, and which land inside it
    in front of the camera (beyond ``near_m``)."""
    _, h, w = views.near_depth.shape
    m = views.camera_from_world[i]
    pc = points @ m[:3, :3].T + m[:3, 3]
    uv, z = project(pc, views.intrinsics[i], min_z=near_m)
    front = z > near_m
    u, v = nearest_pixel(uv)
    return u, v, z, front & (u >= 0) & (u < w) & (v >= 0) & (v < h)


def free_space_hits(points: np.ndarray, views: DepthViews, margin_m: float, near_m: float = 0.1) -> np.ndarray:
    """``[N]`` number of views whose depth rays passed more than ``margin_m`` beyond each point
    ``points [N, 3]`` (in the views' world frame): the point sits in space those views saw empty."""
    hits = np.zeros(len(points), np.int32)
    for i in range(len(views.camera_from_world)):
        u, v, z, inside = _project(points, views, i, near_m)
        near = np.full(len(points), np.nan, np.float32)
        near[inside] = views.near_depth[i][v[inside], u[inside]]
        hits += (np.isfinite(near) & (z < near - margin_m)).astype(np.int32)
    return hits


def seen_through(points: np.ndarray, views: DepthViews, i: int, margin_m: float, near_m: float = 0.1) -> int:
    """Pixels of view ``i`` whose depth ray passed more than ``margin_m`` beyond the nearest of
    ``points [N, 3]`` (in the view's world frame) that projects there: the view saw through a
    surface of the other recording (a z-buffer of the points, compared with the nearest depth)."""
    _, h, w = views.near_depth.shape
    u, v, z, inside = _project(points, views, i, near_m)
    zbuf = np.full(h * w, np.inf)
    np.minimum.at(zbuf, v[inside] * w + u[inside], z[inside])
    near = views.near_depth[i].reshape(-1)
    return int(np.sum(np.isfinite(near) & (zbuf < near - margin_m)))


def on_surface(points: np.ndarray, target: PlaneTarget, inlier_m: float) -> tuple[np.ndarray, np.ndarray]:
    """``[N]`` which of ``points [N, 3]`` lie on ``target`` (point-to-plane within ``inlier_m``,
    nearest neighbour within ``3 * inlier_m``), and ``[N]`` each one's nearest target point."""
    dist, idx = target.tree.query(points, distance_upper_bound=3 * inlier_m, workers=-1)
    ok = np.isfinite(dist)
    agree = np.zeros(len(points), bool)
    plane = np.einsum("ij,ij->i", points[ok] - target.points[idx[ok]], target.normals[idx[ok]])
    agree[np.nonzero(ok)[0][np.abs(plane) < inlier_m]] = True
    return agree, idx


def evidence(
    points: np.ndarray,
    target: PlaneTarget,
    views: DepthViews,
    *,
    inlier_m: float,
    margin_m: float,
    viewpoint: np.ndarray | None = None,
    facing: np.ndarray | None = None,
    back_face_cos: float | None = None,
) -> Evidence:
    """Classify ``points [N, 3]`` (already in the other recording's world frame) against its
    surface ``target`` (point-to-plane within ``inlier_m``, nearest neighbour within
    ``3 * inlier_m``) and its views' free space (``margin_m`` in front of the measured depth).

    With ``viewpoint [3]`` (the camera that saw ``points``, same frame), ``facing`` (``[K, 3]``
    per target point, the side it was seen from: :func:`seen_side`) and ``back_face_cos``, a
    point on the target's surface whose side points away from that camera by more than
    ``acos(-back_face_cos)`` conflicts instead: an opaque surface is not seen from behind. A placement turned 180 deg
    about a vertical line in a wall puts the camera behind the wall, where every point it sees
    lies on the wall's plane (generalization seed 26, a close-up of a cabinet front)."""
    agree, idx = on_surface(points, target, inlier_m)
    behind = np.zeros(len(points), bool)
    if viewpoint is not None and facing is not None and back_face_cos is not None:
        i = np.nonzero(agree)[0]
        to_camera = np.asarray(viewpoint, dtype=np.float64) - points[i]
        cos = np.einsum("ij,ij->i", to_camera, facing[idx[i]])
        behind[i[cos < -back_face_cos * np.linalg.norm(to_camera, axis=1)]] = True
        agree &= ~behind
    conflict = behind | (~agree & (free_space_hits(points, views, margin_m) > 0))
    return Evidence(int(agree.sum()), int(conflict.sum()), len(points), agree, idx)


def motion_scale(points: np.ndarray, up: np.ndarray) -> tuple[np.ndarray, float]:
    """The centroid ``[3]`` of ``points [N, 3]`` and their RMS distance from it across ``up``
    (at least 1 mm): the lever arm that turns a yaw about the centroid into a length."""
    centre = points.mean(0)
    rel = points - centre
    horiz = rel - np.outer(rel @ up, up)
    return centre, max(float(np.sqrt(np.mean(np.sum(horiz**2, axis=1)))), 1e-3)


def seen_side(points: np.ndarray, views: DepthViews, *, margin_m: float, knn: int = 20,
              min_cos: float = 0.2) -> np.ndarray:
    """``[N, 3]`` the side each surface point of ``points [N, 3]`` was seen from: its unit normal
    (a plane through its ``knn`` nearest neighbours) turned towards the views that saw it (it
    projects into them no more than ``margin_m`` behind their depth; ``views`` from
    ``depth_views(..., farthest=True)``). Zero where no view saw
    it, or where they saw it within ``acos(min_cos)`` of edge-on, which leaves the side open.
    The nearest neighbours, not a radius: the fused clouds' own normals are planes within a few
    voxels, which on sparse depth hold too few points and come out arbitrary."""
    cloud = o3d.geometry.PointCloud(o3d.utility.Vector3dVector(np.asarray(points, dtype=np.float64)))
    cloud.estimate_normals(o3d.geometry.KDTreeSearchParamKNN(knn))
    normals = np.asarray(cloud.normals)
    toward = np.zeros_like(normals)
    centres = np.linalg.inv(views.camera_from_world)[:, :3, 3]
    for i in range(len(centres)):
        u, v, z, inside = _project(points, views, i, near_m=0.1)
        depth = np.full(len(points), np.nan, np.float32)
        depth[inside] = views.near_depth[i][v[inside], u[inside]]
        seen = np.isfinite(depth) & (z < depth + margin_m)
        d = centres[i] - points[seen]
        toward[seen] += d / np.linalg.norm(d, axis=1, keepdims=True)
    length = np.linalg.norm(toward, axis=1)
    cos = np.einsum("ij,ij->i", normals, toward) / np.maximum(length, 1e-12)
    side = normals * np.sign(cos)[:, None]
    side[~(np.abs(cos) >= min_cos)] = 0.0
    return side


def weakest_constraint(points: np.ndarray, normals: np.ndarray, up: np.ndarray) -> tuple[float, np.ndarray]:
    """How well matched points pin a yaw-and-translation motion, in its weakest direction.

    Each point on a surface with normal ``n`` measures the motion along ``n`` only, so a set of
    matches on one plane (a floor, or a floor and one wall) leaves a direction free: the
    recording can slide along it. Returns the smallest eigenvalue of the per-point information
    matrix of ``(yaw * r, tx, ty, tz)`` (``r`` the points' RMS horizontal distance from their
    centroid, so all four are lengths): 1/3 for three orthogonal planes in equal shares, 0 for
    a plane, and its direction ``[4]``.
    """
    if len(points) < 10:
        return 0.0, np.zeros(4)
    up = np.asarray(up, dtype=np.float64)
    centre, radius = motion_scale(points, up)
    rel = points - centre
    jac = np.hstack([(np.cross(rel, normals) @ up)[:, None] / radius, normals])
    vals, vecs = np.linalg.eigh(jac.T @ jac / len(points))
    return float(vals[0]), vecs[:, 0]


@dataclass(frozen=True)
class ScoringData:
    """What hypotheses are scored against.

    Attributes:
        static_surface: the static surface (canonical frame) the dynamic points are matched to.
        static_views: the static depth maps whose free space the dynamic points are tested in.
        static_points: ``[N, 3]`` static points (canonical frame) tested against the dynamic views.
        dynamic_points: per scored dynamic frame, its points ``[M_i, 3]`` (session frame), one per
            valid pixel of ``dynamic_views``.
        dynamic_views: those frames' depth maps.
        frame_weights: ``[len(dynamic_points)]`` how much each of those frames counts.
        static_luminance: ``[len(static_surface.points)]`` the static surface's intensity
            (``_texture.luminance`` of its colours); None skips the texture test.
        static_groups: ``[len(static_surface.points)]`` the planar surface each static surface
            point lies on (``_texture.surface_groups``).
        dynamic_luminance: per scored dynamic frame, the intensity ``[M_i]`` of its points.
        static_facing: ``[len(static_surface.points), 3]`` the side each static surface point
            was seen from (:func:`seen_side`); None skips the back-face test.
    """

    static_surface: PlaneTarget
    static_views: DepthViews
    static_points: np.ndarray
    dynamic_points: tuple[np.ndarray, ...]
    dynamic_views: DepthViews
    frame_weights: np.ndarray
    static_luminance: np.ndarray | None = None
    static_groups: np.ndarray | None = None
    dynamic_luminance: tuple[np.ndarray, ...] | None = None
    static_facing: np.ndarray | None = None


def score_hypothesis(
    name: str, transform: np.ndarray, data: ScoringData, up: np.ndarray, *, inlier_m: float, margin_m: float,
    back_face_cos: float | None = None,
) -> HypothesisScore:
    """Evidence for ``transform`` (canonical_from_session), frame by frame of the dynamic points.

    Per frame, support = (points on static surfaces - points in static free space - pixels
    whose ray passed through a static surface) / points; the last term is the same test the
    other way round, and catches a wrong placement that lays the dynamic recording's walls and
    floor onto static ones while the rest of it lands where the static recording never looked
    (its rays then cross the static furniture). The hypothesis' support is the weighted mean;
    its inlier ratio the weighted pooled share of agreeing points among those where the static
    recording looked; its overlap the unweighted share of dynamic points where it looked. A
    point on a static surface seen from behind (``back_face_cos``, see :func:`evidence`) is
    against it. Its
    colour agreement is the mean over frames of the within-surface correlation of the agreeing
    points' intensities with the static ones (``_texture.within_surface_correlation``),
    weighted by frame weight times agreeing points, and its colour contrast the same mean of the
    static texture's RMS; NaN and 0 where no frame has enough texture.
    """
    w = np.asarray(data.frame_weights, dtype=np.float64)
    inverse = np.linalg.inv(transform)
    static_in_session = data.static_points @ inverse[:3, :3].T + inverse[:3, 3]
    agree = conflict = total = 0
    w_agree = w_seen = 0.0
    frame_support = np.zeros(len(data.dynamic_points))
    agreed = []
    colour = []  # (weight, r, contrast) per frame with enough texture
    cameras = np.linalg.inv(data.dynamic_views.camera_from_world)[:, :3, 3] @ transform[:3, :3].T + transform[:3, 3]
    for i, pts in enumerate(data.dynamic_points):
        moved = pts @ transform[:3, :3].T + transform[:3, 3]
        ev = evidence(moved, data.static_surface, data.static_views, inlier_m=inlier_m, margin_m=margin_m,
                      viewpoint=cameras[i], facing=data.static_facing, back_face_cos=back_face_cos)
        crossed = seen_through(static_in_session, data.dynamic_views, i, margin_m)
        frame_support[i] = (ev.agree - ev.conflict - crossed) / max(ev.total, 1)
        agree, conflict, total = agree + ev.agree, conflict + ev.conflict, total + ev.total
        w_agree += w[i] * ev.agree
        w_seen += w[i] * (ev.agree + ev.conflict)
        agreed.append(moved[ev.agree_mask])
        rc = _frame_colour(data, i, ev.agree_mask, ev.matched)
        if rc is not None:
            colour.append((w[i] * ev.agree, *rc))
    points = np.concatenate(agreed) if agreed else np.zeros((0, 3))
    _, idx = data.static_surface.tree.query(points, workers=-1)
    constraint, _ = weakest_constraint(points, data.static_surface.normals[idx], up)
    agreement, contrast = _pooled_colour(colour)
    return HypothesisScore(
        name=name,
        canonical_from_session=np.asarray(transform, dtype=np.float64),
        support=float(np.sum(w * frame_support) / max(np.sum(w), 1e-12)),
        overlap=(agree + conflict) / max(total, 1),
        inlier_ratio=w_agree / max(w_seen, 1e-12),
        constraint=constraint,
        colour_agreement=agreement,
        colour_contrast=contrast,
    )


def _frame_colour(data: ScoringData, i: int, agree: np.ndarray, matched: np.ndarray) -> tuple[float, float] | None:
    """Colour agreement and contrast of scored dynamic frame ``i``'s points on static surfaces
    (``agree [M_i]``, each matched to static surface point ``matched [M_i]``); None without
    luminance or texture."""
    if data.static_luminance is None or data.dynamic_luminance is None or data.static_groups is None:
        return None
    match = matched[agree]
    return within_surface_correlation(data.dynamic_luminance[i][agree], data.static_luminance[match],
                                      data.static_groups[match])


def _pooled_colour(colour: list[tuple[float, float, float]]) -> tuple[float, float]:
    """The frames' ``(weight, agreement, contrast)`` pooled: weighted means; NaN and 0 without any."""
    cw, cr, cc = np.array(colour).T if colour else (np.zeros(1), np.full(1, np.nan), np.zeros(1))
    if np.sum(cw) <= 0:
        return float("nan"), 0.0
    return float(np.sum(cw * cr) / np.sum(cw)), float(np.sum(cw * cc) / np.sum(cw))


def colour_agreement(transform: np.ndarray, data: ScoringData, *, inlier_m: float) -> tuple[float, float]:
    """``(colour agreement, colour contrast)`` of ``transform`` as :func:`score_hypothesis` pools
    them, from the surface matches alone (no free-space or back-face tests: a fraction of the
    cost, for searching placements the geometry already accepts)."""
    w = np.asarray(data.frame_weights, dtype=np.float64)
    colour = []
    for i, pts in enumerate(data.dynamic_points):
        agree, idx = on_surface(pts @ transform[:3, :3].T + transform[:3, 3], data.static_surface, inlier_m)
        rc = _frame_colour(data, i, agree, idx)
        if rc is not None:
            colour.append((w[i] * agree.sum(), *rc))
    return _pooled_colour(colour)
