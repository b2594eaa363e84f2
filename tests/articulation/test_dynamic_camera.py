"""The dynamic recording's own camera (exposure, white balance, vignetting), fitted in stage IV
against the twin: recovered when present, identity within noise when absent, held-out frames
interpolated, and through ``articulate`` on the tiny door scene with the exposure drifting in the
dynamic recording only."""

from __future__ import annotations

from dataclasses import replace

import numpy as np
import pytest

from artitwin_core._errors import InputError
from artitwin_core.articulation import ArticulationConfig, TwinRenderer, articulate
from artitwin_core.articulation._camera import CameraFitConfig, fit_recording_camera, remove_camera
from artitwin_core.diagnostics._residuals import linear_to_srgb, srgb_to_linear
from artitwin_core.synth import BENCHMARK_SCENES, generate_scene


def _images(n=6, h=24, w=32, seed=0):
    rng = np.random.default_rng(seed)
    lin = rng.uniform(0.05, 0.6, (n, h, w, 3))
    return lin


def _to_u8(lin):
    return np.round(np.clip(linear_to_srgb(np.clip(lin, 0, 1)), 0, 1) * 255).astype(np.uint8)


def test_fit_recovers_per_frame_gains_and_is_identity_without_them():
    lin = _images()
    n, h, w, _ = lin.shape
    gains = np.exp(np.random.default_rng(1).normal(0, 0.2, (n, 3)))
    pred = linear_to_srgb(lin)
    k = np.tile([40.0, 40.0, (w - 1) / 2, (h - 1) / 2], (n, 1))
    valid = np.ones((n, h, w), bool)
    cfg = CameraFitConfig()
    model = fit_recording_camera(pred, _to_u8(lin * gains[:, None, None]), valid, range(n), k, cfg)
    assert np.allclose(np.exp(model.log_gain), gains, rtol=0.02), (np.exp(model.log_gain), gains)
    clean = fit_recording_camera(pred, _to_u8(lin), valid, range(n), k, cfg)
    # Measured: 8-bit quantisation alone leaves |log g| < 2e-3 and |o| < 2e-4.
    assert np.abs(clean.log_gain).max() < 0.01 and np.abs(clean.offset).max() < 0.002
    # remove_camera undoes it (up to 8-bit rounding).
    back = remove_camera(_to_u8(lin * gains[:, None, None]), model, range(n), k)
    assert np.abs(back.astype(int) - _to_u8(lin).astype(int)).mean() < 1.0


def test_vignetting_is_fitted_with_the_gains():
    lin = _images(n=4, h=48, w=64)
    n, h, w, _ = lin.shape
    k = np.tile([60.0, 60.0, (w - 1) / 2, (h - 1) / 2], (n, 1))
    from artitwin_core.reconstruction._sensor import radius_sq

    r2 = radius_sq(k[0], w, h)
    v = 1 - 0.3 * r2
    gains = np.array([1.0, 1.2, 0.85, 1.1])[:, None]
    meas = _to_u8(lin * gains[:, :, None, None] * v[None, :, :, None])
    model = fit_recording_camera(linear_to_srgb(lin), meas, np.ones((n, h, w), bool), range(n), k,
                                 CameraFitConfig(effects=("exposure_white_balance", "vignetting")))
    c1, c2 = model.vignetting  # r^2 and r^4 trade off on a small image: compare the falloff itself
    fitted = 1 + c1 * r2 + c2 * r2**2
    assert np.abs(fitted - v).max() < 0.03, model.vignetting
    assert np.allclose(np.exp(model.log_gain[:, 1]), gains[:, 0], rtol=0.03)


def test_heldout_frames_get_interpolated_gains_and_bad_options_are_named():
    lin = _images(n=3)
    n, h, w, _ = lin.shape
    gains = np.array([1.0, 1.3, 1.6])[:, None, None, None]
    k = np.tile([40.0, 40.0, 16, 12], (n, 1))
    model = fit_recording_camera(linear_to_srgb(lin), _to_u8(lin * gains), np.ones((n, h, w), bool), [0, 4, 8], k)
    g, _ = model.frame_gain(2)  # never fitted: between frames 0 and 4, log-linear
    assert g[1] == pytest.approx(np.sqrt(1.3), rel=0.02)
    with pytest.raises(InputError, match="depth_scale_offset"):
        CameraFitConfig(effects=("depth_scale_offset",))
    with pytest.raises(InputError, match="camera_effects"):
        ArticulationConfig(camera_effects=("lens_distortion",))


@pytest.fixture(scope="module")
def drifting_dynamic(tiny_scene):
    """The tiny scene with its dynamic recording's exposure wandering (the static sweep is clean)."""
    spec = replace(BENCHMARK_SCENES["tiny"], effects=(("exposure", {"stops_std": 0.35, "recordings": "dynamic"}),))
    return generate_scene(spec)


def _heldout_rgb_error(result, scene, masks, camera: bool) -> float:
    """Mean absolute linear-RGB error of the twin on the held-out dynamic frames, hand left out."""
    truth, cap = scene.truth, scene.dynamic
    twin = TwinRenderer(result.params, truth.joints, backend="cpu", appearance=result.appearance)
    w, h = cap.rgb_size
    errs = []
    for t in result.test_frames:
        rgb, _, alpha = twin.render([float(j.q[t]) for j in truth.joints], truth.dynamic_world_from_camera[t],
                                    cap.rgb_intrinsics[t], w, h)
        if camera:
            rgb = result.camera.apply_rgb(np.clip(rgb, 0, 1), t, cap.rgb_intrinsics[t])
        ok = (alpha > 0.95) & ~np.asarray(masks.hand[t], bool)
        errs.append(np.abs(srgb_to_linear(np.clip(rgb, 0, 1)) - srgb_to_linear(cap.rgb[t]))[ok].mean())
    return float(np.mean(errs))


@pytest.mark.slow  # four short stage-IV runs: ~4 min on 2 busy cores
def test_articulate_models_the_dynamic_exposure_and_costs_nothing_without_it(
    tiny_scene, drifting_dynamic, true_masks, canonical
):
    base = ArticulationConfig(holdout_every=3, phase1_steps=40, phase2_steps=0, backend="cpu")
    on = replace(base, camera_effects=("exposure_white_balance",))

    def run(scene, config):
        truth = scene.truth
        return articulate(canonical, scene.static, truth.static_world_from_camera, scene.dynamic,
                          truth.dynamic_world_from_camera, true_masks, truth.joints, config)  # fmt: skip

    drift_off, drift_on = run(drifting_dynamic, base), run(drifting_dynamic, on)
    assert drift_off.camera is None and drift_on.camera is not None
    assert set(drift_on.camera.frames) == set(drift_on.train_frames)
    before = _heldout_rgb_error(drift_off, drifting_dynamic, true_masks, camera=False)
    after = _heldout_rgb_error(drift_on, drifting_dynamic, true_masks, camera=True)
    assert after < 0.7 * before, (before, after)
    # On the clean scene the modelled camera is near identity and the held-out error barely moves.
    clean_off, clean_on = run(tiny_scene, base), run(tiny_scene, on)
    assert np.abs(clean_on.camera.log_gain).max() < 0.05, clean_on.camera.log_gain
    e_off = _heldout_rgb_error(clean_off, tiny_scene, true_masks, camera=False)
    e_on = _heldout_rgb_error(clean_on, tiny_scene, true_masks, camera=True)
    assert abs(e_on - e_off) < 0.05 * e_off + 1e-3, (e_off, e_on)
