"""Each injected effect changes what it should and nothing else (noise-free scenes, fixed seed)."""

from __future__ import annotations

import cv2
import numpy as np
import pytest

from artitwin_core.geometry import invert_se3
from artitwin_core.synth import EFFECTS, srgb_to_linear

BASE = {"noise_level": 0.0, "static_frames": 5, "dynamic_frames": 6}


@pytest.fixture(scope="module")
def base(make_scene):
    return make_scene(**BASE)


@pytest.fixture(scope="module")
def with_effect(make_scene):
    def make(name, params=None, **changes):
        return make_scene(**{**BASE, **changes}, effects=((name, params or {}),))

    return make


def _same_depth(a, b):
    np.testing.assert_array_equal(np.isnan(a), np.isnan(b))
    np.testing.assert_array_equal(np.nan_to_num(a), np.nan_to_num(b))


def _unchanged(scene, base, *, rgb=True, depth=True, poses=True):
    for role in ("static", "dynamic"):
        a, b = getattr(scene, role), getattr(base, role)
        if rgb:
            np.testing.assert_array_equal(a.rgb, b.rgb)
        if depth:
            _same_depth(a.depth, b.depth)
            np.testing.assert_array_equal(a.confidence, b.confidence)
        if poses:
            np.testing.assert_array_equal(a.world_from_camera, b.world_from_camera)
    np.testing.assert_array_equal(scene.truth.static_world_from_camera, base.truth.static_world_from_camera)
    np.testing.assert_array_equal(scene.truth.dynamic_world_from_camera, base.truth.dynamic_world_from_camera)
    if rgb:
        np.testing.assert_array_equal(scene.truth.part_masks, base.truth.part_masks)


def test_registry_is_documented_and_recorded(with_effect):
    assert len(EFFECTS) >= 13
    for name, eff in EFFECTS.items():
        assert eff.name == name and len(eff.doc) > 40
        assert eff.target in {"rgb", "depth", "pose", "timing", "lens", "joint"}
    scene = with_effect("depth_bias", {"scale": 1.1})
    assert scene.truth.effects == {"depth_bias": {"scale": 1.1, "offset_m": 0.01, "recordings": "both"}}


def test_depth_bias_scales_and_offsets_valid_depth_only(base, with_effect):
    scene = with_effect("depth_bias", {"scale": 1.05, "offset_m": 0.02})
    _unchanged(scene, base, depth=False)
    for role in ("static", "dynamic"):
        a, b = getattr(scene, role).depth, getattr(base, role).depth
        np.testing.assert_array_equal(np.isnan(a), np.isnan(b))
        ok = np.isfinite(b)
        # float32 depth at <= 5 m: one ulp is 5e-7 m.
        np.testing.assert_allclose(a[ok], 1.05 * b[ok] + 0.02, atol=2e-6)


def test_exposure_changes_rgb_per_frame_but_not_depth(base, with_effect):
    scene = with_effect("exposure", {"stops_std": 0.5})
    _unchanged(scene, base, rgb=False)
    a = srgb_to_linear(scene.static.rgb / 255.0).mean(axis=(1, 2, 3))
    b = srgb_to_linear(base.static.rgb / 255.0).mean(axis=(1, 2, 3))
    log_gain = np.log2(a / b)
    assert np.std(log_gain) > 0.05  # the gain varies from frame to frame
    assert np.max(np.abs(log_gain)) < 2.5  # ~ within 5 sigma of 0.5 stops (clipping shrinks it)


def test_white_balance_changes_red_and_blue_not_green(base, with_effect):
    scene = with_effect("white_balance", {"gain_std": 0.1})
    _unchanged(scene, base, rgb=False)
    np.testing.assert_array_equal(scene.static.rgb[..., 1], base.static.rgb[..., 1])
    ratio = scene.static.rgb[..., 0].astype(float).mean(axis=(1, 2)) / base.static.rgb[..., 0].mean(axis=(1, 2))
    assert np.max(np.abs(ratio - 1)) > 0.01


def test_vignetting_darkens_corners_by_the_strength(base, with_effect):
    s = 0.4
    scene = with_effect("vignetting", {"strength": s})
    _unchanged(scene, base, rgb=False)
    a = srgb_to_linear(scene.static.rgb / 255.0).mean(-1)
    b = srgb_to_linear(base.static.rgb / 255.0).mean(-1)
    fx, fy, cx, cy = base.static.rgb_intrinsics[0]
    icx, icy = int(round(cx)), int(round(cy))
    centre = a[:, icy - 2:icy + 3, icx - 2:icx + 3].sum() / b[:, icy - 2:icy + 3, icx - 2:icx + 3].sum()
    # 8-bit quantisation of bright pixels: ratios good to ~1 %.
    assert abs(centre - 1) < 0.01
    corner = a[:, :3, :3].sum() / b[:, :3, :3].sum()
    w, h = base.spec.rgb_size
    r2 = max((cx) ** 2 + (cy) ** 2, (w - 1 - cx) ** 2 + cy**2, cx**2 + (h - 1 - cy) ** 2, (w - 1 - cx) ** 2 + (h - 1 - cy) ** 2)
    expected = 1 - s * (cx**2 + cy**2) / r2  # the top-left corner pixel
    assert abs(corner - expected) < 0.03


def test_depth_noise_follows_sigma_a_plus_b_z_squared(base, with_effect, make_scene):
    a_m, b_per_m = 0.004, 0.006
    noisy = with_effect("depth_noise", {"a_m": a_m, "b_per_m": b_per_m}, noise_level=1.0)
    z = base.static.depth
    ok = np.isfinite(z)
    np.testing.assert_array_equal(np.isfinite(noisy.static.depth), ok)
    zscore = (noisy.static.depth[ok] - z[ok]) / (a_m + b_per_m * z[ok].astype(np.float64) ** 2)
    # ~10^4 samples: the std of a unit normal is estimated within ~1 %; 5 % allows float32 rounding.
    assert zscore.size > 5000
    assert abs(np.std(zscore) - 1) < 0.05 and abs(np.mean(zscore)) < 0.05
    # Far depth is noisier than near depth, as sigma grows with z^2.
    near, far = z[ok] < np.median(z[ok]), z[ok] >= np.median(z[ok])
    diff = noisy.static.depth[ok] - z[ok]
    assert np.std(diff[far]) > 1.3 * np.std(diff[near])
    # The effect touches depth only: RGB equals the same noise level without it.
    plain = make_scene(**{**BASE, "noise_level": 1.0})
    np.testing.assert_array_equal(noisy.static.rgb, plain.static.rgb)
    # A shorter maximum range invalidates exactly the depth beyond it.
    short = with_effect("depth_noise", {"max_range_m": 2.0})
    np.testing.assert_array_equal(np.isfinite(short.static.depth), ok & (z <= 2.0))


def test_time_offset_samples_depth_and_pose_later_than_rgb(base, with_effect):
    dt = base.spec.static_stride / 30.0  # exactly one kept frame later
    scene = with_effect("time_offset", {"seconds": dt})
    _unchanged(scene, base, depth=False, poses=False)
    np.testing.assert_allclose(scene.static.world_from_camera[:-1], base.truth.static_world_from_camera[1:], atol=1e-9)
    same = np.isclose(scene.static.depth[:-1], base.static.depth[1:], atol=1e-5, equal_nan=True)
    assert same.mean() > 0.999  # identical up to rays that graze an edge
    assert not np.allclose(scene.static.depth[0], base.static.depth[0], equal_nan=True)


def test_pose_lag_records_each_frame_with_an_earlier_pose_and_keeps_the_images(base, with_effect):
    dt = 2 * base.spec.static_stride / 30.0  # two kept frames late
    scene = with_effect("pose_lag", {"seconds": dt})
    _unchanged(scene, base, poses=False)
    # Frame i is recorded with the pose the camera had two frames earlier; the images are untouched.
    np.testing.assert_allclose(scene.static.world_from_camera[2:], base.truth.static_world_from_camera[:-2], atol=1e-9)
    dyn = scene.truth.canonical_from_dynamic_session @ scene.dynamic.world_from_camera
    dt_d = 2 * base.spec.dynamic_stride / 30.0
    early = with_effect("pose_lag", {"seconds": dt_d, "recordings": "dynamic"})
    dyn_early = early.truth.canonical_from_dynamic_session @ early.dynamic.world_from_camera
    np.testing.assert_allclose(dyn_early[2:], base.truth.dynamic_world_from_camera[:-2], atol=1e-9)
    assert not np.allclose(dyn[1:], base.truth.dynamic_world_from_camera[1:], atol=1e-6)


def test_an_effect_scoped_to_one_recording_leaves_the_other_alone(base, with_effect):
    scene = with_effect("exposure", {"stops_std": 0.5, "recordings": "dynamic"})
    np.testing.assert_array_equal(scene.static.rgb, base.static.rgb)
    assert not np.array_equal(scene.dynamic.rgb, base.dynamic.rgb)
    with pytest.raises(Exception, match="recordings"):
        with_effect("exposure", {"recordings": "both-ish"})
    with pytest.raises(Exception, match="unknown parameters"):
        with_effect("axis_sag", {"recordings": "dynamic"})  # a joint effect moves the part in both


def test_pose_drift_grows_with_time_in_recorded_poses_only(base, with_effect):
    scene = with_effect("pose_drift", {"trans_m_per_s": 0.05, "yaw_rad_per_s": 0.02})
    _unchanged(scene, base, poses=False)
    err = np.linalg.norm(scene.static.world_from_camera[:, :3, 3] - base.truth.static_world_from_camera[:, :3, 3], axis=1)
    assert err[0] < 1e-12 and np.all(np.diff(err) > 0)
    t_last = scene.static.timestamps[-1]
    assert err[-1] > 0.05 * t_last  # at least the translation drift
    dyn = scene.truth.canonical_from_dynamic_session @ scene.dynamic.world_from_camera
    err_d = np.abs(dyn - scene.truth.dynamic_world_from_camera).max(axis=(1, 2))
    assert err_d[0] < 1e-12 and err_d[-1] > 1e-2


def test_pose_jitter_is_small_white_noise_on_recorded_poses(base, with_effect):
    rot_std, trans_std = 0.004, 0.003
    scene = with_effect("pose_jitter", {"rot_std_rad": rot_std, "trans_std_m": trans_std})
    _unchanged(scene, base, poses=False)
    rel = invert_se3(base.truth.static_world_from_camera) @ scene.static.world_from_camera
    ang = np.arccos(np.clip((np.trace(rel[:, :3, :3], axis1=1, axis2=2) - 1) / 2, -1, 1))
    trans = np.linalg.norm(rel[:, :3, 3], axis=1)
    assert np.all(ang > 0) and np.all(ang < 5 * rot_std)
    assert np.all(trans > 0) and np.all(trans < 5 * np.sqrt(3) * trans_std)


def test_lens_distortion_warps_rgb_and_is_recorded_only_when_asked(base, with_effect):
    coeffs = {"k1": -0.12, "k2": 0.03, "p1": 0.001, "p2": -0.001}
    honest = with_effect("lens_distortion", {**coeffs, "record": True})
    hidden = with_effect("lens_distortion", {**coeffs, "record": False})
    _unchanged(honest, base, rgb=False)
    np.testing.assert_allclose(honest.static.distortion, list(coeffs.values()))
    assert hidden.static.distortion is None and base.static.distortion is None
    np.testing.assert_array_equal(hidden.static.rgb, honest.static.rgb)
    # Undistorting the recorded RGB with the true coefficients recovers the pinhole image: the RGB
    # really went through this lens model. Compared blurred (point-sampled texture aliases) and
    # off-centre, where the lens moves pixels by 1-6 px.
    fx, fy, cx, cy = base.static.rgb_intrinsics[0]
    k = np.array([[fx, 0, cx], [0, fy, cy], [0, 0, 1]])
    w, h = base.spec.rgb_size
    mx, my = cv2.initUndistortRectifyMap(k, np.array(list(coeffs.values())), None, k, (w, h), cv2.CV_32FC1)
    uu, vv = np.meshgrid(np.arange(w), np.arange(h))
    region = (np.hypot((uu - cx) / fx, (vv - cy) / fy) > 0.4) & (mx > 2) & (mx < w - 3) & (my > 2) & (my < h - 3)

    def blur(img):
        return cv2.GaussianBlur(img.astype(np.float32).mean(-1), (0, 0), 1.5)

    raw_err, und_err = [], []
    for i in range(base.static.num_frames):
        ref = blur(base.static.rgb[i])
        raw_err.append(np.abs(blur(honest.static.rgb[i]) - ref)[region].mean())
        und = cv2.remap(honest.static.rgb[i], mx, my, cv2.INTER_LINEAR)
        und_err.append(np.abs(blur(und) - ref)[region].mean())
    # Measured (seed 7, 128x96): 0.92 grey levels after undistortion vs 2.33 before.
    assert np.mean(und_err) < 0.5 * np.mean(raw_err), (und_err, raw_err)
    # Masks follow the recorded (distorted) image.
    assert np.any(honest.truth.part_masks != base.truth.part_masks)


def test_rolling_shutter_skews_top_and_bottom_rows_most(base, with_effect):
    scene = with_effect("rolling_shutter", {"readout_s": 0.1})
    _unchanged(scene, base, rgb=False)
    diff = np.abs(scene.static.rgb.astype(float) - base.static.rgb).mean(axis=(0, 2, 3))
    h = diff.shape[0]
    mid = diff[h // 2 - 3:h // 2 + 3].mean()
    assert diff[:6].mean() > 2 * mid and diff[-6:].mean() > 2 * mid


def test_supersampling_smooths_rgb_and_keeps_masks_and_depth(base, make_scene):
    smooth = make_scene(**BASE, rgb_supersample=2)
    _unchanged(smooth, base, rgb=False)
    np.testing.assert_array_equal(smooth.truth.part_masks, base.truth.part_masks)
    diff = np.abs(smooth.static.rgb.astype(float) - base.static.rgb)
    # Averaging four sub-pixel rays changes edges and fine texture, not the overall exposure.
    assert 0.3 < diff.mean() < 8 and abs(smooth.static.rgb.mean() - base.static.rgb.mean()) < 1.0
    # Smoother: less energy in horizontal pixel-to-pixel differences.
    grad = [np.abs(np.diff(s.static.rgb.astype(float), axis=2)).mean() for s in (smooth, base)]
    assert grad[0] < grad[1]
