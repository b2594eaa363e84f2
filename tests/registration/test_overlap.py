"""Registration where the recordings overlap only in part, share one AR session, or do not overlap.

Issue 24: a real phone recording split in two halves (one session: the truth is the identity)
came back rotated 45 degrees, 40 of them a tilt away from gravity, and part_masks then found five
moving parts where nothing moved. Measured here (SMALL scene, seed 21, default noise):
partial overlap static frames 10-13 (34 % of the dynamic points seen by both) 0.003 deg / 0.4 mm
at the furniture, frames 0-2 (39 %) 0.07 deg / 1.9 mm; the static sweep's two halves 0.02 deg /
0.5 mm, tilt 0; views the static recording never saw are refused, and a corner of the room laid onto
another corner (geometrically a perfect fit) is refused by its texture alone. (With the coloured ICP
before the photometric refinement: 2.7, 4.7 and 4.9 mm.)
"""

from __future__ import annotations

import pickle
from dataclasses import replace

import numpy as np
import pytest

from artitwin_core import InputError
from artitwin_core.geometry import invert_se3
from artitwin_core.registration import (
    HypothesisScore,
    RegistrationConfig,
    RegistrationError,
    register_recordings,
)
from artitwin_core.synth import generate_scene
from tests.registration.conftest import SMALL, overlap_fraction, pose_errors, rendered_recording

FAST = RegistrationConfig(uncertainty_blocks=0)  # the block jackknife is tested in test_register


def furniture_error(estimate: np.ndarray, truth: np.ndarray, size_m) -> float:
    """Largest displacement (metres) of the cabinet's eight corners under ``estimate`` vs ``truth``."""
    w, h, d = size_m
    corners = np.array([[x, y, z, 1.0] for x in (-w / 2, w / 2) for y in (0.0, h) for z in (-d, 0.0)]).T
    return float(np.linalg.norm((estimate @ invert_se3(truth) @ corners - corners)[:3], axis=0).max())


@pytest.mark.parametrize("frames", [slice(10, 14), slice(0, 3)])
def test_partial_overlap_registers(small_scene, frames):
    """The static sweep cut to one end of its arc: a third of the dynamic recording seen by both."""
    s = small_scene
    static = s.static.select_frames(frames)
    truth = s.truth.canonical_from_dynamic_session
    assert 0.3 <= overlap_fraction(static, s.dynamic, truth) <= 0.6  # measured 0.34, 0.39
    r = register_recordings(static, s.dynamic, config=FAST)
    rot, _ = pose_errors(r.canonical_from_session, truth)
    assert rot < 0.5  # issue 24 target; measured 0.003, 0.07 deg
    assert furniture_error(r.canonical_from_session, truth, s.spec.size_m) < 0.01  # measured 0.4, 1.9 mm
    assert r.hypotheses[0].overlap > 0.5 and r.hypotheses[0].inlier_ratio > 0.85  # measured 0.68-0.78, 0.92
    assert r.diagnostics["verdict"]["failed"] == []
    assert r.diagnostics["final"]["colour_agreement"] > 0.5  # the same texture: measured 0.70, 0.65


def test_same_session_halves_recover_the_identity(small_scene):
    """One recording cut in two: both halves are in one AR session, so the answer is the identity."""
    s = small_scene
    n = s.static.num_frames // 2
    first, second = s.static.select_frames(slice(0, n)), s.static.select_frames(slice(n, None))
    r = register_recordings(first, second, config=FAST)
    rot, _ = pose_errors(r.canonical_from_session, np.eye(4))
    assert rot < 0.5  # measured 0.02 deg
    assert r.tilt_deg <= 0.3  # measured 0 (the free tilt, 0.1 deg, is not significant)
    assert furniture_error(r.canonical_from_session, np.eye(4), s.spec.size_m) < 0.01  # measured 0.5 mm
    assert r.diagnostics["final"]["colour_agreement"] > 0.5  # measured 0.82


@pytest.mark.parametrize(
    ("eyes", "targets"),
    [
        # The front wall, behind the static sweep's cameras.
        (((-0.6, 1.3, 1.4), (0.6, 1.3, 1.4)), ((-0.6, 1.0, 3.2), (0.6, 1.0, 3.2))),
        # The front-left corner of the room.
        (((-1.0, 1.3, 1.6), (-0.7, 1.3, 1.6)), ((-2.3, 0.8, 2.4), (-2.3, 0.8, 3.2))),
    ],
    ids=["front-wall", "front-left-corner"],
)
def test_views_the_static_recording_never_saw_are_refused(small_scene, eyes, targets):
    s = small_scene
    t = np.linspace(0.0, 1.0, 8)[:, None]
    eyes, targets = np.asarray(eyes), np.asarray(targets)
    dynamic = rendered_recording(s, eyes[0] + t * (eyes[1] - eyes[0]), targets[0] + t * (targets[1] - targets[0]),
                                 invert_se3(s.truth.canonical_from_dynamic_session))
    assert overlap_fraction(s.static, dynamic, s.truth.canonical_from_dynamic_session) < 0.01
    with pytest.raises(RegistrationError) as info:
        register_recordings(s.static, dynamic, config=FAST)
    err = info.value
    assert isinstance(err, InputError)
    message = str(err)
    for needle in ("Best hypothesis", "support", "overlap", "inliers", "Failed:", "What to do"):
        assert needle in message
    assert err.failed and all(isinstance(f, str) for f in err.failed)
    assert err.hypotheses and isinstance(err.hypotheses[0], HypothesisScore)
    again = pickle.loads(pickle.dumps(err))
    assert str(again) == message and again.failed == err.failed


def test_a_corner_laid_onto_another_corner_is_refused_by_its_texture():
    """Issue 24: renders of the room's front-left corner, which the static sweep never saw, fit another
    corner's walls and floor (overlap 48 %, 98 % of it on static surfaces); only the texture differs.

    With the rival test switched off, so that the texture test decides alone. Measured: colour
    agreement -0.03 on texture of RMS 0.085 (0.4-0.9 at the right placement)."""
    s = generate_scene(replace(SMALL, furniture="drawer", seed=3))
    t = np.linspace(0.0, 1.0, 8)[:, None]
    eyes, targets = np.array([[-1.0, 1.3, 1.6], [-0.7, 1.3, 1.6]]), np.array([[-2.3, 0.8, 2.4], [-2.3, 0.8, 3.2]])
    truth = s.truth.canonical_from_dynamic_session
    dynamic = rendered_recording(s, eyes[0] + t * (eyes[1] - eyes[0]), targets[0] + t * (targets[1] - targets[0]),
                                 invert_se3(truth))
    assert overlap_fraction(s.static, dynamic, truth) < 0.01
    with pytest.raises(RegistrationError) as info:
        register_recordings(s.static, dynamic, config=replace(FAST, max_rival_ratio=1.01))
    err = info.value
    assert len(err.failed) == 1 and "colours correlate" in err.failed[0]
    best = err.hypotheses[0]
    assert best.overlap > 0.3 and best.inlier_ratio > 0.9  # the geometric tests pass: measured 0.48, 0.98
    assert best.colour_agreement < 0.1 and best.colour_contrast > 0.05  # measured -0.03, 0.085
    assert f"colour agreement {best.colour_agreement:.2f}" in str(err)


def test_refusal_can_be_turned_off(small_scene):
    """With ``refuse_unconvincing=False`` the best hypothesis comes back with its scores."""
    s = small_scene
    eyes = np.array([[-0.6, 1.3, 1.4], [0.6, 1.3, 1.4]])
    targets = np.array([[-0.6, 1.0, 3.2], [0.6, 1.0, 3.2]])
    dynamic = rendered_recording(s, eyes, targets, invert_se3(s.truth.canonical_from_dynamic_session))
    cfg = RegistrationConfig(refuse_unconvincing=False, uncertainty_blocks=0, photometric_blur_rad=())
    r = register_recordings(s.static, dynamic, config=cfg)
    assert r.diagnostics["verdict"]["failed"]
    assert r.hypotheses[0].as_dict()["name"] == r.diagnostics["global"]["chosen"]


def test_tilt_within_the_bound_is_found(clean_small_scene):
    """The dynamic session's gravity 0.3 deg off: the free tilt is significant and kept.

    Measured (noise-free): tilt 0.300 deg (jackknife SE 0.01 deg), 0.4 mm at the furniture (2.3 mm
    with the coloured ICP before the photometric refinement); 5.7 mm
    with ``max_tilt_deg=0`` (gravity kept exactly)."""
    from artitwin_core.geometry import axis_angle_to_matrix, make_se3

    s = clean_small_scene
    tilt = make_se3(axis_angle_to_matrix(np.array([1.0, 0.0, 0.3]), np.radians(0.3)), np.zeros(3))
    dynamic = replace(s.dynamic, world_from_camera=tilt @ s.dynamic.world_from_camera)
    truth = s.truth.canonical_from_dynamic_session @ invert_se3(tilt)
    r = register_recordings(s.static, dynamic, config=FAST)
    assert r.diagnostics["tilt"]["kept"]
    assert abs(r.tilt_deg - 0.3) < 0.1
    assert furniture_error(r.canonical_from_session, truth, s.spec.size_m) < 0.004  # measured 0.4 mm
