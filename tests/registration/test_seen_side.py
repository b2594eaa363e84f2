"""Registration uses which side of a surface was seen, slides to the texture where shapes cannot pin
it, and takes a small overlap that the texture confirms.

Generalization seed 26 (issue 24): a close-up of a cabinet front in both recordings. The placement
turned 180 deg about a vertical line in the front puts the dynamic camera behind the cabinet, where
every point it sees still lies on the front's plane: it scored 0.47 against the true placement's
0.33 and won (the drawer was then exported in that turned frame). With the surfaces' seen side, its
points are seen from behind and count against it (-0.43). The true placement then came out of ICP
8 cm along the front (the close-up pins nothing along it) with colour agreement -0.11, and was
refused for its texture; sliding along the free direction to where the texture agrees brings it to
0.19 mm. Seed 12 was refused for its overlap (24 %, under min_overlap 30 %) although 93 % of it lay
on static surfaces and its texture agreed at 0.82.
"""

from __future__ import annotations

from dataclasses import replace

import numpy as np
import pytest

from artitwin_core.geometry import invert_se3
from artitwin_core.registration import RegistrationConfig, register_recordings
from artitwin_core.registration._evidence import evidence
from artitwin_core.registration._gravity_icp import PlaneTarget
from artitwin_core.registration._register import _Clouds, _Scorer, _scoring_data, _texture_search
from artitwin_core.synth import generate_scene, random_scene_spec
from tests.registration.conftest import pose_errors

UP = np.array([0.0, 1.0, 0.0])


def test_the_side_each_static_point_was_seen_from(small_scene):
    """Floors face up, the cabinet's front faces the room: the static cameras' side."""
    s = small_scene
    cfg = RegistrationConfig()
    keep = np.ones(s.dynamic.num_frames)
    data = _scoring_data(s.static, s.dynamic, _Clouds(s.static, s.dynamic, keep, UP, cfg), UP, keep, cfg)
    points, side = data.static_surface.points, data.static_facing
    judged = np.any(side != 0, axis=1)
    assert judged.mean() > 0.9  # measured 0.985
    floor = judged & (points[:, 1] < 0.02) & (np.abs(side[:, 1]) > 0.7)
    assert floor.sum() > 200 and np.mean(side[floor, 1] > 0) > 0.99  # measured 5942 points, all up
    front = judged & (np.abs(points[:, 2]) < 0.01) & (points[:, 1] > 0.1) & (np.abs(side[:, 2]) > 0.7)
    assert front.sum() > 50 and np.mean(side[front, 2] > 0) > 0.99  # the front at z = 0 faces +z: 76, all


def test_a_surface_seen_from_behind_counts_against():
    rng = np.random.default_rng(0)
    grid = np.arange(-1.0, 1.0, 0.02)
    plane = np.stack(np.meshgrid(grid, grid, [0.0]), -1).reshape(-1, 3)  # z = 0, seen from +z
    target = PlaneTarget.of(plane, np.tile([0.0, 0.0, 1.0], (len(plane), 1)))
    views = _no_views()
    points = np.c_[rng.uniform(-0.5, 0.5, (300, 2)), rng.normal(0, 0.002, 300)]
    kw = dict(inlier_m=0.02, margin_m=0.05, back_face_cos=0.25)
    side = np.tile([0.0, 0.0, 1.0], (len(plane), 1))
    front = evidence(points, target, views, viewpoint=np.array([0.0, 0.0, 1.5]), facing=side, **kw)
    behind = evidence(points, target, views, viewpoint=np.array([0.0, 0.0, -1.5]), facing=side, **kw)
    grazing = evidence(points, target, views, viewpoint=np.array([0.0, 30.0, -1.5]), facing=side, **kw)
    unknown = evidence(points, target, views, viewpoint=np.array([0.0, 0.0, -1.5]), facing=0 * side, **kw)
    assert front.agree == 300 and front.conflict == 0
    assert behind.agree == 0 and behind.conflict == 300
    assert grazing.agree == 300  # 93 deg from the normal: within back_face_cos, not judged
    assert unknown.agree == 300  # no side known: not judged
    assert evidence(points, target, views, viewpoint=np.array([0.0, 0.0, -1.5]), inlier_m=0.02, margin_m=0.05).agree == 300


def _no_views():
    from artitwin_core.registration._evidence import DepthViews

    return DepthViews(np.eye(4)[None], np.array([[10.0, 10.0, 5.0, 5.0]]), np.full((1, 10, 10), np.nan, np.float32))


def test_texture_search_slides_to_where_the_texture_agrees(small_scene):
    """The static surface is cut to what a close-up of a front leaves (no normal along x), so the
    shapes cannot tell a slide along x; started 8 cm off, the texture search returns. This room's
    texture varies slowly enough that 8 cm off it still agrees at 0.51 (seed 26's front: -0.11),
    so the gate is raised to 0.6 here to make the search run."""
    s = small_scene
    cfg = replace(RegistrationConfig(), min_colour_agreement=0.6)
    truth = s.truth.canonical_from_dynamic_session
    keep = np.ones(s.dynamic.num_frames)
    data = _scoring_data(s.static, s.dynamic, _Clouds(s.static, s.dynamic, keep, UP, cfg), UP, keep, cfg)
    facing = np.abs(data.static_surface.normals[:, 0]) < 0.2
    data = replace(data, static_surface=PlaneTarget.of(data.static_surface.points[facing], data.static_surface.normals[facing]),
                   static_luminance=data.static_luminance[facing], static_groups=data.static_groups[facing])
    score = _Scorer(data, UP, cfg)
    start = truth.copy()
    start[0, 3] += 0.08
    found, info = _texture_search(start, score, UP, cfg)
    assert info["agreement_before"] < cfg.min_colour_agreement and info["accepted"]
    error = found @ invert_se3(truth)
    assert np.linalg.norm(error[:3, 3]) < 0.012  # measured 0.5 mm
    assert info["agreement_after"] > 0.6  # measured 0.69

    same, info = _texture_search(truth, score, UP, cfg)  # the texture agrees: nothing moves
    assert info["moved_m"] == 0.0 and np.array_equal(same, truth)


@pytest.mark.slow
@pytest.mark.parametrize(
    ("seed", "why"),
    [
        (12, "a static close-up: 24 % of the dynamic points where the static recording looked, texture agreeing"),
        (26, "a close-up of a drawer front: turned 180 deg behind it, then 8 cm along it"),
    ],
)
def test_generalization_scenes_register(seed, why):
    """Two generalization scenes (issue 24) that were refused or registered wrong (seed 11, a box
    room whose turned placement the seen side now rules out, takes 10 s more and is left to the
    benchmark). Measured at the true pivot: 1.5 and 1.2 mm; rotation 0.05 and 0.003 deg."""
    s = generate_scene(random_scene_spec(seed))
    truth = s.truth.canonical_from_dynamic_session
    r = register_recordings(s.static, s.dynamic, config=RegistrationConfig(uncertainty_blocks=0))
    rot, _ = pose_errors(r.canonical_from_session, truth)
    error = r.canonical_from_session @ invert_se3(truth)
    pivots = np.array([j.pivot for j in s.truth.joints])
    assert rot < 0.5, why
    assert np.linalg.norm(pivots @ error[:3, :3].T + error[:3, 3] - pivots, axis=1).max() < 0.01, why
    assert r.diagnostics["final"]["colour_agreement"] > 0.5  # measured 0.84, 0.72
