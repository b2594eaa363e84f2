"""A door's hinge line from the planes its faces show in depth (``fit_line_from_planes``) and
through ``refine_joint_states``.

Two tiers, as elsewhere: a slab made of points (no renderer) with random axes, pivots and
thicknesses, exact without noise and within a millimetre with 2 mm depth noise; and the ``tiny``
rendered scene with true masks and registration, where the line the tracks leave on a white door
(1 cm off along the door's normal, 1 deg tilted) is pulled back onto the truth. Measured: slab
seeds 0-5, 2 mm noise: axis <= 0.03 deg, pivot <= 0.32 mm, thickness <= 0.11 mm; ``tiny``
(noise level 1): axis 0.23 deg, pivot 2.5 mm against 1.0 deg and 10 mm in, states within 0.22
deg; noise-free ``tiny``: 0.002 deg and 0.015 mm.
"""

from dataclasses import replace

import numpy as np
import pytest

from artitwin_core.joints import (
    Joint,
    StateRefineConfig,
    fit_line_from_planes,
    joint_errors,
    refine_joint_states,
)
from artitwin_core.joints._model import rotations_about
from artitwin_core.masks import MaskSequence
from artitwin_core.synth import BENCHMARK_SCENES, generate_scene


def _slab_frames(seed: int, noise_m: float, curved: bool = False):
    """Points a depth camera sees on a hinged slab door, frame by frame, in the canonical frame.

    The door (0.6 x 0.8 m, ``thickness`` deep) hangs on a random axis through a random pivot;
    frames 0-4 are at rest, the rest swing it out to 70 deg. The camera stands in front of the
    closed door, off to its free edge: it sees the front face, then (the door turned past its
    line of sight) the inside face; frames within 10 deg of edge-on see a sliver of the front.
    Each point is moved along its ray by Gaussian noise of ``noise_m`` metres.
    """
    rng = np.random.default_rng(seed)
    axis = rng.normal(size=3)
    axis /= np.linalg.norm(axis)
    helper = np.eye(3)[np.argmin(np.abs(axis))]
    across = np.cross(axis, helper)
    across /= np.linalg.norm(across)
    normal = np.cross(axis, across)  # front face normal at rest: positive q swings the door out
    pivot = rng.uniform(-0.5, 0.5, size=3)
    thickness = rng.uniform(0.015, 0.03)
    u, v = np.meshgrid(np.linspace(0.02, 0.58, 40), np.linspace(-0.38, 0.38, 50))
    u, v = u.ravel(), v.ravel()
    bulge = 0.08 * np.sin(np.pi * u / 0.6) if curved else 0.0
    front = pivot + np.outer(u, across) + np.outer(v, axis) + np.outer(thickness + bulge, normal)
    inside = pivot + np.outer(u, across) + np.outer(v, axis) + np.outer(bulge, normal)
    q = np.concatenate([np.zeros(5), np.radians(np.linspace(3.0, 70.0, 15))])
    cam = pivot + 0.9 * across + 0.6 * normal
    lifted, cams = [], []
    for qt in q:
        rot = rotations_about(axis, np.array([qt]))[0]
        centre = rot @ (0.3 * across + thickness * normal) + pivot
        facing = float((cam - centre) @ (rot @ normal)) / np.linalg.norm(cam - centre)
        face = front if facing > np.sin(np.radians(10)) else inside if facing < -np.sin(np.radians(10)) else front[:40]
        pts = (face - pivot) @ rot.T + pivot
        ray = pts - cam
        ray /= np.linalg.norm(ray, axis=1, keepdims=True)
        pts = pts + rng.normal(scale=noise_m, size=(len(pts), 1)) * ray if noise_m > 0 else pts
        lifted.append((pts, None))
        cams.append(cam)
    truth = Joint("revolute", axis, pivot, q, np.array([0.0, q.max()]), np.zeros(q.size), np.ones(q.size))
    return lifted, np.array(cams), truth, thickness


def _biased(truth: Joint, shift_m: float, tilt_deg: float) -> Joint:
    """``truth`` with its pivot moved ``shift_m`` along the door normal and its axis tilted."""
    helper = np.eye(3)[np.argmin(np.abs(truth.axis))]
    off = np.cross(truth.axis, helper)
    off /= np.linalg.norm(off)
    axis = truth.axis + np.tan(np.radians(tilt_deg)) * off
    return replace(truth, axis=axis / np.linalg.norm(axis), pivot=truth.pivot + shift_m * np.cross(truth.axis, off))


@pytest.mark.parametrize("seed", range(6))
def test_slab_line_is_recovered(seed):
    lifted, cams, truth, thickness = _slab_frames(seed, noise_m=0.0)
    fit = fit_line_from_planes(_biased(truth, 0.01, 1.0), lifted, cams, StateRefineConfig())
    assert fit is not None
    e = joint_errors(replace(truth, axis=fit.axis, pivot=fit.pivot), truth)
    assert e.axis_angle_deg < 1e-3 and e.pivot_to_line_m < 1e-5
    assert abs(fit.thickness_m - thickness) < 1e-5
    np.testing.assert_allclose(fit.q[fit.fitted], truth.q[fit.fitted], atol=1e-5)
    assert fit.inside.sum() >= 3  # the inside face was used

    lifted, cams, truth, thickness = _slab_frames(seed, noise_m=0.002)
    fit = fit_line_from_planes(_biased(truth, 0.01, 1.0), lifted, cams, StateRefineConfig())
    assert fit is not None
    e = joint_errors(replace(truth, axis=fit.axis, pivot=fit.pivot), truth)
    assert e.axis_angle_deg < 0.1, e
    assert e.pivot_to_line_m < 0.001, e
    assert abs(fit.thickness_m - thickness) < 0.001


def test_a_part_that_is_not_a_slab_is_left_to_the_tracks():
    lifted, cams, truth, _ = _slab_frames(0, noise_m=0.001, curved=True)
    assert fit_line_from_planes(_biased(truth, 0.01, 1.0), lifted, cams, StateRefineConfig()) is None


def test_prismatic_joint_has_no_line_to_fit():
    lifted, cams, truth, _ = _slab_frames(0, noise_m=0.0)
    assert fit_line_from_planes(replace(truth, joint_type="prismatic"), lifted, cams, StateRefineConfig()) is None


@pytest.mark.parametrize(("noise", "axis_deg", "pivot_m"), [(0.0, 0.05, 0.0005), (1.0, 0.5, 0.005)])
def test_refine_pulls_a_tracks_line_onto_the_door(noise, axis_deg, pivot_m):
    scene = generate_scene(replace(BENCHMARK_SCENES["tiny"], noise_level=noise))
    truth = scene.truth
    masks = MaskSequence(
        part=truth.part_masks, hand=truth.hand_masks, score=np.ones(scene.dynamic.num_frames, np.float32)
    )
    joint_true = truth.joints[0]
    start = replace(
        _biased(joint_true, 0.01, 1.0),
        residual=np.full(joint_true.q.size, 1e-3),
        confidence=np.ones(joint_true.q.size),
        q_range=np.array([0.0, joint_true.q.max()]),
    )
    before = joint_errors(start, joint_true)
    assert before.axis_angle_deg > 0.9 and before.pivot_to_line_m > 0.009
    out = refine_joint_states(start, scene.dynamic, masks, 1, truth.canonical_from_dynamic_session)
    after = joint_errors(out, joint_true)
    assert after.axis_angle_deg < axis_deg, after
    assert after.pivot_to_line_m < pivot_m, after
    assert np.degrees(np.abs(out.q - joint_true.q)).max() < 1.0
    # Held fixed when asked.
    held = refine_joint_states(
        start, scene.dynamic, masks, 1, truth.canonical_from_dynamic_session, StateRefineConfig(refine_axis=False)
    )
    np.testing.assert_array_equal(held.axis, start.axis)
    np.testing.assert_array_equal(held.pivot, start.pivot)
