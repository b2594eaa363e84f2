"""register_recordings recovers known session transforms on synthetic scenes.

Measured errors: noise-free 96x72-depth scene 0.006 deg / 0.3 mm (the translation along the
cabinet's width is weakly constrained by the geometry; the photometric refinement pins it: 2.5 mm
with the coloured ICP it replaced); same scene with default noise and large yaw/offset 0.04 deg /
0.9-3.2 mm (at the session origin). Bounds are issue 5's targets (0.5 deg, 1 cm) or tighter where
the measurements allow.
"""

from __future__ import annotations

from dataclasses import replace

import numpy as np
import pytest

from artitwin_core import InputError
from artitwin_core.capture import Capture
from artitwin_core.geometry import axis_angle_to_matrix, invert_se3, make_se3
from artitwin_core.registration import RegistrationConfig, register_recordings
from artitwin_core.synth import BENCHMARK_SCENES, generate_scene
from tests.registration.conftest import pose_errors


def _moved(capture: Capture, session_from_old: np.ndarray) -> Capture:
    """The same recording written in another session frame."""
    return replace(capture, world_from_camera=session_from_old @ capture.world_from_camera)


def test_clean_scene_recovers_transform_tightly(clean_small_scene):
    s = clean_small_scene
    r = register_recordings(s.static, s.dynamic)
    rot, trans = pose_errors(r.canonical_from_session, s.truth.canonical_from_dynamic_session)
    assert rot < 0.1  # measured 0.006 deg
    assert trans < 0.01  # measured 0.3 mm (2.5 mm with the coloured ICP)
    assert r.residual_m < 0.001  # median point-to-plane distance of inliers; measured 0.08 mm
    assert r.inlier_fraction > 0.6  # the opened door and unseen areas are the outliers


@pytest.mark.parametrize(("yaw_deg", "offset"), [(170.0, (3.0, 0.2, -2.5)), (-95.0, (-1.5, -0.1, 2.0))])
def test_large_yaw_and_offset_noisy(small_scene, yaw_deg, offset):
    s = small_scene
    extra = make_se3(axis_angle_to_matrix(np.array([0.0, 1.0, 0.0]), np.radians(yaw_deg)), np.array(offset))
    dynamic = _moved(s.dynamic, extra)
    truth = s.truth.canonical_from_dynamic_session @ invert_se3(extra)
    r = register_recordings(s.static, dynamic)
    rot, trans = pose_errors(r.canonical_from_session, truth)
    assert rot < 0.5  # issue 5 target; measured 0.04 deg
    assert trans < 0.01  # issue 5 target; measured 0.9-3.2 mm
    assert {"fuse", "global", "icp_0.02", "icp_0.01", "photometric", "total_seconds"} <= set(r.diagnostics)


def test_gravity_is_a_parameter(small_scene):
    """Both sessions tilted so gravity points along -z: the yaw sweep must use the given axis."""
    s = small_scene
    tilt = make_se3(axis_angle_to_matrix(np.array([1.0, 0.0, 0.0]), np.radians(90.0)), np.zeros(3))
    static = _moved(s.static, tilt)
    dynamic = _moved(s.dynamic, tilt)
    gravity = tilt[:3, :3] @ np.array([0.0, -1.0, 0.0])
    truth = tilt @ s.truth.canonical_from_dynamic_session @ invert_se3(tilt)
    r = register_recordings(static, dynamic, gravity=gravity)
    rot, trans = pose_errors(r.canonical_from_session, truth)
    assert rot < 0.5
    assert trans < 0.01


def test_bad_inputs_raise_input_error(small_scene):
    with pytest.raises(InputError, match="gravity"):
        register_recordings(small_scene.static, small_scene.dynamic, gravity=(0.0, 0.0, 0.0))
    empty = replace(small_scene.dynamic, depth=np.full_like(small_scene.dynamic.depth, np.nan))
    with pytest.raises(InputError, match="valid depth points"):
        register_recordings(small_scene.static, empty)


def test_strong_hand_occlusion_does_not_slide_along_the_front():
    """The benchmark's strong-hand-occlusion scene with fewer frames (same seed, hand, texture).

    With the coloured ICP it replaced, colour term at 0.1 weight (lambda_geometric 0.9), the shared Tukey kernel
    dropped most colour residuals (three quarters at the true pose on the full scene) and the result slid along the cabinet front:
    measured -14.3 mm on this scene (15.2 mm on the full benchmark scene); 3.3 mm at lambda 0.99. Measured now
    (photometric refinement): 0.08 mm.
    """
    spec = replace(
        BENCHMARK_SCENES["strong-hand-occlusion"],
        static_frames=20,
        static_stride=6,
        dynamic_frames=15,
        dynamic_stride=4,
    )
    s = generate_scene(spec)
    r = register_recordings(s.static, s.dynamic)
    truth = s.truth.canonical_from_dynamic_session
    rot, _ = pose_errors(r.canonical_from_session, truth)
    # Error of the canonical frame itself (at the cabinet, not at the dynamic session's origin).
    err = (r.canonical_from_session @ invert_se3(truth))[:3, 3]
    assert rot < 0.5  # measured 0.05 deg
    assert np.linalg.norm(err) < 0.006  # issue 5 target is 1 cm; measured 0.08 mm (3.3 with the coloured ICP)
    assert r.diagnostics["photometric"]["accepted"]
    # The block jackknife's uncertainty at the cabinet covers that error (error / SE measured 0.03;
    # high-noise below 0.2). The jackknife reruns the point-to-plane ICP only, so along a direction
    # that the texture pins and the geometry does not it overstates the uncertainty.
    assert _error_over_se(r, truth, np.array([0.0, spec.size_m[1] / 2, 0.0])) < 3.0


@pytest.mark.slow
def test_noisy_depth_gets_normals_wide_enough():
    """The benchmark's high-noise scene (3x depth noise, pose jitter, exposure) with fewer frames.

    Normals fitted within 3 voxels (3 cm) of a surface with ~1 cm of noise tilt with it, and
    point-to-plane ICP slides along the tilt: measured 4.95 mm at the furniture on this scene with
    ``normal_noise_radii=0`` and a free 6-DOF ICP (6.2 mm on the full benchmark scene). With normals
    from 6 times the surface noise (here 8.7 mm, so 5.2 cm): 2.2 mm (2.1 mm on the full scene).
    Since the ICP keeps gravity (issue 24) the narrow normals cannot tilt it: 2.5 mm with them.
    """
    spec = replace(
        BENCHMARK_SCENES["high-noise"], static_frames=14, static_stride=8, dynamic_frames=12, dynamic_stride=5
    )
    s = generate_scene(spec)
    truth = s.truth.canonical_from_dynamic_session
    w, h, d = spec.size_m
    corners = np.array([[x, y, z, 1.0] for x in (-w / 2, w / 2) for y in (0.0, h) for z in (-d, 0.0)]).T

    def furniture_error(transform: np.ndarray) -> float:
        return float(np.linalg.norm((transform @ invert_se3(truth) @ corners - corners)[:3], axis=0).max())

    r = register_recordings(s.static, s.dynamic)
    assert 0.005 < r.diagnostics["fuse"]["surface_noise_m"] < 0.015  # measured 8.7 mm
    assert furniture_error(r.canonical_from_session) < 0.0035  # measured 1.4 mm (2.2 with the coloured ICP)
    narrow = register_recordings(s.static, s.dynamic, config=RegistrationConfig(normal_noise_radii=0.0, uncertainty_blocks=0))
    assert furniture_error(narrow.canonical_from_session) < 0.0035  # measured 1.5 mm (4.95 mm with 6-DOF ICP)
    assert _error_over_se(r, truth, np.array([0.0, h / 2, 0.0])) < 3.0
    assert narrow.covariance is None  # no blocks, no jackknife


def _error_over_se(result, truth: np.ndarray, point: np.ndarray) -> float:
    """The registration's error at ``point`` over its standard error there (RMS over axes)."""
    from artitwin_core.joints._model import skew

    e = result.canonical_from_session @ invert_se3(truth)
    err = e[:3, :3] @ point + e[:3, 3] - point
    assert result.covariance is not None and result.covariance.shape == (6, 6)
    assert np.all(np.linalg.eigvalsh(result.covariance) > -1e-12)
    jac = np.hstack([-skew(point), np.eye(3)])
    se = float(np.sqrt(np.trace(jac @ result.covariance @ jac.T)))
    assert 1e-4 < se < 0.01  # a tenth of a millimetre to a centimetre: it measures something
    return float(np.linalg.norm(err)) / se
