"""The photometric refinement pins the slide the geometry leaves free (issue 24).

On generalization scenes whose two recordings share only a cabinet front, the floor and a wall,
the point-to-plane stages left the slide along the front free and the coloured ICP between the
fused clouds did not pin it: 17-86 mm off (random scenes 0, 4, 5). Here the static surface is cut
down to what such an overlap leaves, the points whose normals have no component along the front
(x), so the geometry cannot tell a slide along it at all; started 6 cm off along x, the
point-to-plane ICP stays there (measured 60.0 mm) and the photometric refinement returns to the
truth (measured 0.9 mm; 0.02 deg).
"""

from __future__ import annotations

import numpy as np

from artitwin_core.geometry import invert_se3
from artitwin_core.registration import RegistrationConfig, fused_cloud
from artitwin_core.registration._gravity_icp import PlaneTarget, gravity_icp
from artitwin_core.registration._photometric import photometric_refine

UP = np.array([0.0, 1.0, 0.0])


def test_texture_pins_the_slide_the_geometry_leaves_free(small_scene):
    s = small_scene
    cfg = RegistrationConfig()
    truth = s.truth.canonical_from_dynamic_session
    voxel = 0.01
    static = fused_cloud(s.static, range(s.static.num_frames), voxel_m=voxel)
    points, normals = np.asarray(static.points), np.asarray(static.normals)
    facing = np.abs(normals[:, 0]) < 0.2  # floor, walls and fronts facing y or z: x is free
    target = PlaneTarget.of(points[facing], normals[facing])
    frames = [0, 1, 2]  # before the door moves
    dynamic = np.asarray(fused_cloud(s.dynamic, frames, voxel_m=voxel).points)
    start = truth.copy()
    start[0, 3] += 0.06

    def error(transform: np.ndarray) -> tuple[float, np.ndarray]:
        e = transform @ invert_se3(truth)  # at the cabinet: the canonical origin is its front's centre
        return float(np.degrees(np.arccos(np.clip((np.trace(e[:3, :3]) - 1) / 2, -1, 1)))), e[:3, 3]

    icp = gravity_icp(dynamic, target, start, UP, max_distance_m=2.5 * voxel, kernel_m=1.5 * voxel)
    assert abs(error(icp.transform)[1][0]) > 0.03  # measured 48 mm: little pulls it back

    r = photometric_refine(
        s.static, s.dynamic, frames, target, dynamic, start, UP, blur_rad=cfg.photometric_blur_rad,
        num_views=cfg.photometric_views, max_points=cfg.photometric_points, visibility_m=cfg.photometric_visibility_m,
        max_distance_m=2.5 * voxel, kernel_m=1.5 * voxel, grey_noise=cfg.photometric_noise, stride=cfg.pixel_stride,
        max_depth_m=cfg.max_depth_m, min_confidence=cfg.min_confidence,
    )
    rot, t = error(r.transform)
    assert rot < 0.1  # measured 0.02 deg
    assert np.linalg.norm(t) < 0.004  # measured 0.9 mm
    assert len(r.levels) == len(cfg.photometric_blur_rad) and all(level["points"] > 500 for level in r.levels)
