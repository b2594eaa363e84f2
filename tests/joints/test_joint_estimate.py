"""estimate_joint on trajectories made from ground-truth joints: two tolerance tiers, fixed seeds.

Tolerances were set from measured errors (seeds 100-105, 200 tracks x 20 frames, 15% outlier
tracks, 10% invalid entries) with about 3x headroom; the measured worst case is written beside
each bound.
"""

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from artitwin_core import InputError
from artitwin_core.joints import (
    Joint,
    JointFitConfig,
    axis_angle_error_deg,
    estimate_joint,
    joint_errors,
    joint_transforms,
    random_part_joint,
    simulate_trajectories,
)
from artitwin_core.tracking import Trajectories

N_TRACKS, N_FRAMES = 200, 20


def _scene(kind, seed, noise_m, outliers=0.15, invalid=0.1, n=N_TRACKS, t=N_FRAMES, **kw):
    rng = np.random.default_rng(seed)
    truth, pts = random_part_joint(kind, n, t, rng)
    traj, is_part = simulate_trajectories(
        truth, pts, rng, noise_m=noise_m, outlier_fraction=outliers, invalid_fraction=invalid, **kw
    )
    return truth, pts, traj, is_part


@pytest.mark.parametrize("kind", ["revolute", "prismatic", "screw"])
@pytest.mark.parametrize("seed", [1, 2])
def test_noise_free_recovers_joint_exactly(kind, seed):
    truth, pts, traj, is_part = _scene(kind, seed, noise_m=0.0)
    fit = estimate_joint(traj)
    e = joint_errors(fit.joint, truth)
    assert e.type_correct
    # Measured over seeds 1000-1005 (300 tracks, 30 frames): axis <= 3e-13 deg, pivot <= 2e-15 m,
    # state <= 2e-13 deg or 3e-9 m. The bounds are the brief's tight tier.
    assert e.axis_angle_deg < 1e-3
    if kind == "prismatic":
        assert e.state_error_m < 1e-5
    else:
        assert e.pivot_error_m < 1e-4
        assert e.pivot_to_line_m < 1e-4
        assert e.state_error_deg < 1e-3
    if kind == "screw":
        assert e.pitch_error_m_per_rad < 1e-5
    # Sign convention: q = 0 at the reference frame, the widest opening is positive.
    assert fit.joint.q[0] == 0.0
    assert fit.joint.q_range[1] > 0 and fit.joint.q_range[1] >= abs(fit.joint.q_range[0])
    # Every track that truly follows the part is kept.
    assert not np.any(is_part & ~fit.inlier_mask)
    # The RANSAC per-frame motions equal the true ones. A track that slid off the part by less
    # than the 0.1 mm minimum gate can stay in a frame's consensus and shift its Kabsch solution
    # (measured <= 7e-6 in a few frames, 1e-15 elsewhere); the joint fit's gate drops it.
    true_m = joint_transforms(truth.joint_type, truth.axis, truth.pivot, truth.q, truth.pitch)
    err = np.abs(fit.rigid_motions - true_m).max(axis=(1, 2))
    assert np.nanmax(err) < 5e-4
    assert np.nanmedian(err) < 1e-9
    assert np.all(np.nan_to_num(fit.joint.residual) < 1e-4)


@pytest.mark.parametrize("kind", ["revolute", "prismatic", "screw"])
@pytest.mark.parametrize("seed", [100, 101, 102])
def test_noisy_2mm_within_bounds(kind, seed):
    truth, pts, traj, is_part = _scene(kind, seed, noise_m=0.002)
    fit = estimate_joint(traj)
    e = joint_errors(fit.joint, truth)
    assert e.type_correct, [(h.joint_type, h.bic) for h in fit.hypotheses]
    assert e.axis_angle_deg < 0.3  # measured <= 0.12 deg over seeds 100-105
    if kind == "prismatic":
        assert e.state_error_m < 0.001  # measured <= 0.3 mm
        assert e.range_error_m < 0.002
    else:
        assert e.pivot_error_m < 0.002  # measured <= 0.33 mm
        assert e.state_error_deg < 0.25  # measured <= 0.065 deg
        assert e.range_error_deg < 0.5
    # The noise estimate is the per-coordinate sigma (within 15%: median-based, some outliers).
    assert abs(fit.noise_sigma_m - 0.002) < 0.0003
    assert not np.any(is_part & ~fit.inlier_mask)  # measured: no part track lost
    # Outliers kept are those indistinguishable from the part (background by the hinge, tracks
    # sliding off late while the part rests): measured <= 10 of 30.
    assert np.sum(~is_part & fit.inlier_mask) <= 0.5 * np.sum(~is_part)
    finite = np.isfinite(fit.joint.residual)
    assert np.all(fit.joint.residual[finite] < 0.002 * 3)  # RMS of a 3D residual ~ sqrt(3) sigma


def test_noise_growing_with_depth():
    # sigma = 1 mm at 1 m, times depth^2 (1-3 m): 1-9 mm.
    truth, pts, traj, _ = _scene("revolute", 7, noise_m=0.001, noise_grows_with_depth=True)
    e = joint_errors(estimate_joint(traj).joint, truth)
    assert e.type_correct
    assert e.axis_angle_deg < 0.5 and e.pivot_error_m < 0.005 and e.state_error_deg < 0.5


@pytest.mark.parametrize("noise_m", [0.0, 0.002, 0.005])
def test_nothing_moved_is_fixed(noise_m):
    truth, pts, traj, _ = _scene("fixed", 3, noise_m=noise_m)
    fit = estimate_joint(traj)
    assert fit.joint.joint_type == "fixed", [(h.joint_type, h.bic) for h in fit.hypotheses]
    assert np.all(fit.joint.q == 0) and np.all(fit.joint.q_range == 0)


def _with_travel(truth: Joint, scale: float) -> Joint:
    q = truth.q * scale
    return Joint(
        truth.joint_type,
        truth.axis,
        truth.pivot,
        q,
        np.array([q.min(), q.max()]),
        truth.residual,
        truth.confidence,
        truth.pitch,
    )


def test_motion_below_floor_is_fixed_and_above_is_detected():
    rng = np.random.default_rng(5)
    truth, pts = random_part_joint("prismatic", N_TRACKS, N_FRAMES, rng)
    tiny = _with_travel(truth, 0.001 / np.abs(truth.q).max())  # 1 mm of travel, noise 2 mm
    traj, _ = simulate_trajectories(tiny, pts, rng, noise_m=0.002, outlier_fraction=0.15)
    assert estimate_joint(traj).joint.joint_type == "fixed"
    small = _with_travel(truth, 0.02 / np.abs(truth.q).max())  # 2 cm of travel
    traj, _ = simulate_trajectories(small, pts, rng, noise_m=0.002, outlier_fraction=0.15)
    fit = estimate_joint(traj)
    assert fit.joint.joint_type == "prismatic"
    assert abs(fit.joint.q_range[1] - 0.02) < 0.001


def test_reference_frame_defines_closed_state():
    truth, pts, traj, _ = _scene("revolute", 11, noise_m=0.001)
    ref = N_FRAMES - 1
    fit = estimate_joint(traj, reference_frame=ref)
    assert fit.joint.q[ref] == 0.0
    q = truth.q - truth.q[ref]
    shifted = Joint(
        truth.joint_type,
        truth.axis,
        truth.pivot,
        q,
        np.array([q.min(), q.max()]),
        truth.residual,
        truth.confidence,
    )
    e = joint_errors(fit.joint, shifted)
    assert e.type_correct and e.axis_angle_deg < 0.3 and e.pivot_error_m < 0.002
    assert e.state_error_deg < 0.25


def test_low_confidence_frame_is_smoothed_without_lag():
    rng = np.random.default_rng(21)
    truth, pts = random_part_joint("revolute", N_TRACKS, N_FRAMES, rng)
    traj, _ = simulate_trajectories(truth, pts, rng, noise_m=0.002)
    # Frame k keeps only the 4 tracks nearest the hinge: a lever arm of a few cm, so q[k] is
    # poorly determined there (standard error ~ sigma / lever ~ degrees).
    k = int(np.argmax(np.abs(np.diff(truth.q))))  # mid-opening, where lag would show
    arm = np.linalg.norm(np.cross(truth.axis, pts - truth.pivot), axis=-1)
    keep = np.argsort(arm)[:4]
    valid = traj.valid.copy()
    valid[k] = False
    valid[k, keep] = True
    pts_w = np.where(valid[..., None], traj.points_in_world, np.nan)
    fit = estimate_joint(Trajectories(pts_w, traj.pixels, valid, 0))
    assert fit.joint.confidence[k] < 0.5 < np.median(fit.joint.confidence)
    # Smoothed from its neighbours with a centred quadratic: no lag at the steepest frame.
    assert abs(np.degrees(fit.joint.q[k] - truth.q[k] * np.sign(truth.q[np.argmax(np.abs(truth.q))]))) < 0.3
    confident = fit.joint.confidence >= 0.5
    e = joint_errors(fit.joint, truth)
    assert e.state_error_deg < 0.25 and confident.sum() == N_FRAMES - 1


def test_bad_inputs_raise_input_error():
    truth, pts, traj, _ = _scene("revolute", 1, noise_m=0.0, outliers=0.0, invalid=0.0, n=20, t=5)
    with pytest.raises(InputError, match="reference_frame"):
        estimate_joint(traj, reference_frame=5)
    with pytest.raises(InputError, match="valid"):
        estimate_joint(Trajectories(traj.points_in_world, traj.pixels, traj.valid[:, :3], 0))
    valid = traj.valid.copy()
    valid[0, 2:] = False
    with pytest.raises(InputError, match="reference frame 0 has 2 valid tracks"):
        estimate_joint(Trajectories(traj.points_in_world, traj.pixels, valid, 0))
    with pytest.raises(ValueError, match="inlier_sigmas"):
        JointFitConfig(inlier_sigmas=0.0)


unit3 = st.tuples(*[st.floats(-1, 1)] * 3).map(np.array).filter(lambda v: np.linalg.norm(v) > 0.2)


@settings(max_examples=12, deadline=None)
@given(
    kind=st.sampled_from(["revolute", "prismatic"]),
    axis=unit3,
    offset=unit3,
    q_max=st.floats(0.1, 1.6),
    centre=st.tuples(*[st.floats(-3, 3)] * 3).map(np.array),
    seed=st.integers(0, 2**16),
)
def test_property_noise_free_fit_over_random_axes_angles_poses(kind, axis, offset, q_max, centre, seed):
    rng = np.random.default_rng(seed)
    axis = axis / np.linalg.norm(axis)
    pts = centre + rng.uniform(-0.3, 0.3, size=(60, 3))
    pivot = centre + 0.4 * offset  # the hinge up to 0.7 m from the part's centre
    q = q_max * np.sin(np.linspace(0, np.pi / 2, 8)) ** 2
    if kind == "prismatic":
        q = q * 0.2  # up to 0.32 m
    truth = Joint(kind, axis, pivot, q, np.array([0.0, q.max()]), np.zeros(8), np.ones(8))
    traj, _ = simulate_trajectories(truth, pts, rng, outlier_fraction=0.1)
    fit = estimate_joint(traj)
    e = joint_errors(fit.joint, truth)
    assert e.type_correct
    assert e.axis_angle_deg < 1e-3
    if kind == "revolute":
        assert e.pivot_error_m < 1e-4 and e.state_error_deg < 1e-3
    else:
        assert e.state_error_m < 1e-5


def test_screw_needs_real_axial_travel():
    rng = np.random.default_rng(8)
    truth, pts = random_part_joint("screw", N_TRACKS, N_FRAMES, rng)
    travel = abs(truth.pitch) * np.ptp(truth.q)
    # Same axis and angles with 2 mm of axial travel over the whole range: below the 5 mm that
    # min_screw_travel_m asks for, so the simpler revolute must be chosen.
    small = Joint(
        "screw",
        truth.axis,
        truth.pivot,
        truth.q,
        truth.q_range,
        truth.residual,
        truth.confidence,
        truth.pitch * 0.002 / travel,
    )
    traj, _ = simulate_trajectories(small, pts, rng, noise_m=0.002, outlier_fraction=0.15)
    fit = estimate_joint(traj)
    assert fit.joint.joint_type == "revolute", [(h.joint_type, h.bic) for h in fit.hypotheses]
    traj, _ = simulate_trajectories(truth, pts, rng, noise_m=0.002, outlier_fraction=0.15)
    assert travel > 0.01 and estimate_joint(traj).joint.joint_type == "screw"


def _with_frame_errors(traj: Trajectories, axis: np.ndarray, offsets_m: np.ndarray) -> Trajectories:
    """Every track of frame t shifted by ``offsets_m[t]`` along ``axis``: an error shared by the
    tracks of a frame (a slid homography, a depth bias), which per-point BIC counts N times."""
    pts = traj.points_in_world + offsets_m[:, None, None] * axis[None, None, :]
    return Trajectories(pts, traj.pixels, traj.valid, traj.query_frame)


def test_frame_level_axial_drift_is_not_a_screw():
    rng = np.random.default_rng(21)
    truth, pts = random_part_joint("revolute", N_TRACKS, N_FRAMES, rng)
    traj, _ = simulate_trajectories(truth, pts, rng, noise_m=0.001)
    # Axial drift as a random walk of 1.5 mm steps (as the tracker's on "tiny"): it grows with
    # time, so partly with q, but scatters about any line through it.
    offsets = np.concatenate([[0.0], np.cumsum(rng.normal(0.0, 0.0015, N_FRAMES - 1))])
    fit = estimate_joint(_with_frame_errors(traj, truth.axis, offsets))
    # Per-point BIC alone prefers the screw here (it fits a pitch to the scatter) ...
    assert fit.score("screw").bic + 10.0 < fit.score("revolute").bic
    # ... but the pitch is not significant against the frames' scatter: revolute.
    assert fit.joint.joint_type == "revolute"
    assert axis_angle_error_deg(fit.joint.axis, truth.axis) < 1.0


def test_screw_is_kept_under_frame_level_axial_scatter():
    rng = np.random.default_rng(22)
    truth, pts = random_part_joint("screw", N_TRACKS, N_FRAMES, rng)
    travel = abs(truth.pitch) * np.ptp(truth.q)
    traj, _ = simulate_trajectories(truth, pts, rng, noise_m=0.001)
    offsets = rng.normal(0.0, 0.003, N_FRAMES)
    offsets[0] = 0.0
    fit = estimate_joint(_with_frame_errors(traj, truth.axis, offsets))
    assert travel > 0.02  # measured 0.0xx m: well above the 3 mm scatter
    assert fit.joint.joint_type == "screw", [(h.joint_type, h.bic) for h in fit.hypotheses]
    # The pitch is signed along the axis, so flipping the axis (and q) keeps it.
    assert abs(fit.joint.pitch - truth.pitch) < 0.1 * abs(truth.pitch)  # measured 0.4 %


def test_translation_with_a_sliver_of_rotation_is_prismatic():
    """A drawer whose tracks pick up a milliradian of spurious rotation as it slides out: the
    revolute fit (an axis tens of metres away) may win the BIC, but it does not turn the part."""
    rng = np.random.default_rng(23)
    truth, pts = random_part_joint("prismatic", N_TRACKS, N_FRAMES, rng)
    traj, _ = simulate_trajectories(truth, pts, rng, noise_m=0.001)
    centre = pts.mean(0)
    side = np.cross(truth.axis, [0.0, 0.0, 1.0])
    side /= np.linalg.norm(side)
    p = traj.points_in_world.copy()
    for t in range(N_FRAMES):
        ang = 0.004 * truth.q[t] / truth.q.max()
        m = joint_transforms("revolute", side, centre + truth.q[t] * truth.axis, np.array([ang]))[0]
        p[t] = p[t] @ m[:3, :3].T + m[:3, 3]
    fit = estimate_joint(Trajectories(p, traj.pixels, traj.valid, traj.query_frame))
    assert fit.joint.joint_type == "prismatic"
    assert axis_angle_error_deg(fit.joint.axis, truth.axis) < 1.0


def test_revolute_state_is_wrapped_against_the_reference():
    """The alternation may leave the reference frame's angle near +pi and an opened frame's near
    -pi (the same door, turned a little): q must come out as the small turn, not ~2 pi. Seen on
    door+drawer as a 356 deg range before the wrap."""
    from artitwin_core.joints import joint_motion
    from artitwin_core.joints._finalize import _finalize
    from artitwin_core.joints._fit import _Fit

    rng = np.random.default_rng(0)
    axis, pivot = np.array([0.0, 1.0, 0.0]), np.array([0.4, 0.45, 0.0])
    closed = rng.uniform(-0.3, 0.3, (40, 3)) + [0.0, 0.45, 0.05]
    true_q = np.array([0.0, 0.05, 0.3, 0.6])
    rot, tr = joint_motion("revolute", axis, pivot, true_q, 0.0)
    y = np.einsum("tij,nj->tni", rot, closed) + tr[:, None, :]
    # The fit's gauge: latent points turned by -(pi - 0.05) so that q(ref) = pi - 0.05.
    offset = np.pi - 0.05
    r0, t0 = joint_motion("revolute", axis, pivot, np.array([-offset]), 0.0)
    latent = closed @ r0[0].T + t0[0]
    q_fit = np.mod(true_q + offset + np.pi, 2 * np.pi) - np.pi  # [pi-0.05, pi, -pi+0.25, -pi+0.55]
    fit = _Fit("revolute", axis, pivot, 0.0, q_fit, latent, np.ones((4, 40)), np.ones(40, bool), np.full(4, 1e-3))
    joint, _ = _finalize(fit, 0, y, 1e-3, JointFitConfig())
    np.testing.assert_allclose(joint.q, true_q, atol=1e-9)
    np.testing.assert_allclose(joint.q_range, [0.0, 0.6], atol=1e-9)


def test_tracker_rotation_errors_are_not_a_pitch():
    """The pipeline's own tracks of "low-texture-door" (a revolute door): 150 of its tracks over
    frames 0-18, saved from track_part_points at a502432. The tracker's per-frame rotations are
    10-30 mrad off on this weakly textured face, and the screw's fit tilts its axis 4.4 deg so
    that the tilt's leak of the swing along the axis reads as 31 mm of travel at t = 11 against
    the frames' scatter (the test on the screw's own axis chose "screw"). Tested along the
    revolute's axis (1.5 deg off), the same frames' axial motion is not significant (t = 2.7).
    On these 150 tracks: screw travel 24 mm, axis 4.4 deg off; t = 3.3 along the revolute's."""
    from pathlib import Path

    data = np.load(Path(__file__).parent / "data" / "low_texture_door_tracks.npz")
    pts = data["points_in_world"].astype(np.float64)
    traj = Trajectories(pts, np.zeros(pts.shape[:2] + (2,), np.float32), data["valid"], 0)
    fit = estimate_joint(traj)
    screw = fit.score("screw").joint
    # The per-point BIC and the travel alone would take the screw ...
    assert fit.score("screw").bic + 10.0 < fit.score("revolute").bic
    assert abs(screw.pitch) * np.ptp(screw.q_range) > JointFitConfig().min_screw_travel_m  # measured 24 mm
    # ... which is the tilted one: the revolute is both the right type and the better axis.
    assert axis_angle_error_deg(screw.axis, data["axis_true"]) > 3.0  # measured 4.4
    assert fit.joint.joint_type == "revolute", [(h.joint_type, h.bic) for h in fit.hypotheses]
    # The frame-level refit keeps the frames' in-plane turns from steering the axis.
    assert axis_angle_error_deg(fit.joint.axis, data["axis_true"]) < 1.0  # measured 0.46 (1.65 per point)


def _frame_error_scene(seed: int, mode: str) -> tuple[Joint, Trajectories]:
    """A revolute part whose tracks carry errors shared by each frame, as the tracker's do:
    "slide": every track of the frames past half the opening moved 6 mm along the hinge (a
    door's grain); "turn": every opened frame turned about the part's normal through its
    tracks' centroid by N(0, 20 mrad) (a weakly textured face)."""
    from scipy.spatial.transform import Rotation

    rng = np.random.default_rng(seed)
    truth, pts = random_part_joint("revolute", N_TRACKS, N_FRAMES, rng)
    traj, _ = simulate_trajectories(truth, pts, rng, noise_m=0.001)
    p = traj.points_in_world.copy()
    a = truth.axis
    if mode == "slide":
        p[np.abs(truth.q) > 0.5 * np.abs(truth.q).max()] += 0.006 * a
    else:
        rot = joint_transforms("revolute", a, truth.pivot, truth.q)[:, :3, :3]
        arm = pts.mean(0) - truth.pivot
        arm -= (arm @ a) * a
        normal = np.cross(a, arm / np.linalg.norm(arm))
        for t in np.nonzero(np.abs(truth.q) > 1e-9)[0]:
            c = np.nanmean(p[t][traj.valid[t]], 0)
            turn = Rotation.from_rotvec(rng.normal(0.0, 0.02) * (rot[t] @ normal)).as_matrix()
            p[t] = (p[t] - c) @ turn.T + c
    return truth, Trajectories(p, traj.pixels, traj.valid, traj.query_frame)


@pytest.mark.parametrize(
    ("mode", "seed", "plain_min", "refit_max"),
    # measured per point / frame level: slide 1.37 / 0.06 and 0.81 / 0.02 deg, turn 0.34 / 0.03
    # and 0.52 / 0.02 deg
    [("slide", 30, 0.6, 0.2), ("slide", 33, 0.6, 0.2), ("turn", 33, 0.2, 0.1), ("turn", 35, 0.2, 0.1)],
)
def test_frame_level_errors_do_not_steer_the_hinge(mode, seed, plain_min, refit_max):
    """Errors shared by a frame's tracks are one sample per frame, not one per track: the
    per-point fit tilts the axis to explain them, the frame-level refit weighs each motion
    component by how much the frames scatter in it."""
    truth, traj = _frame_error_scene(seed, mode)
    plain = estimate_joint(traj, JointFitConfig(frame_gls_iterations=0)).joint
    fit = estimate_joint(traj).joint
    assert plain.joint_type == fit.joint_type == "revolute"
    assert axis_angle_error_deg(plain.axis, truth.axis) > plain_min
    assert axis_angle_error_deg(fit.axis, truth.axis) < refit_max
