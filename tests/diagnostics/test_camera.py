"""The camera effects' building blocks against the generator's own models: the undistortion, the
image velocity of the recorded camera path, and what the effects need before they apply."""

from __future__ import annotations

from dataclasses import replace

import numpy as np
import pytest

from artitwin_core import InputError
from artitwin_core.diagnostics import (
    LensDistortion,
    PoseDrift,
    RollingShutter,
    TimeOffset,
    make_residual_data,
)
from artitwin_core.diagnostics._camera import _project, _undistort, image_velocity, rgb_world_points
from artitwin_core.synth._generate import scene_model
from artitwin_core.synth._motion import camera_path
from artitwin_core.synth._render import undistort_normalized
from tests.diagnostics._scenes import residual_data, scene
from tests.diagnostics.test_effects import DENSE


def test_undistortion_matches_the_generator():
    rng = np.random.default_rng(0)
    xd, yd = rng.uniform(-0.7, 0.7, (2, 500))
    coeffs = (-0.08, 0.02, 0.0005, -0.0005)
    x, y = _undistort(xd, yd, *coeffs)
    xr, yr = undistort_normalized(xd, yd, coeffs)
    assert np.abs(x - xr).max() < 1e-9 and np.abs(y - yr).max() < 1e-9


def test_lens_displacement_is_zero_without_distortion_and_grows_to_the_corners():
    data = residual_data("door")
    d0 = LensDistortion().displacement(data, np.zeros(4))
    assert np.abs(d0).max() == 0.0
    d = np.linalg.norm(LensDistortion().displacement(data, np.array([-0.08, 0.02, 0.0, 0.0])), axis=-1)
    assert d[0, 0, 0] > 3.0 > 0.1 > d[0, 48, 64]  # barrel: corners move ~3.8 px, the centre not at all


def test_image_velocity_predicts_the_true_image_motion():
    # time_offset: the recorded poses are the camera path 0.05 s later than the RGB exposure. The
    # true displacement of each predicted point between the two poses against 0.05 s x velocity.
    effects = (("time_offset", {}),)
    sc, data = scene("door", effects, **DENSE), residual_data("door", effects, **DENSE)
    path = camera_path(scene_model(sc.spec), sc.spec.seed, "static", float(sc.static.timestamps[-1]))
    assert np.abs(path.world_from_camera(sc.static.timestamps + 0.05) - data.world_from_camera).max() < 1e-12
    x, y, _ = _project(rgb_world_points(data), data.rgb_intrinsics, path.world_from_camera(sc.static.timestamps))
    t_count, h, w = data.rgb_valid.shape
    u, v = np.meshgrid(np.arange(w), np.arange(h))
    true = np.stack([u[None] - x, v[None] - y], -1)
    est = 0.05 * image_velocity(data)
    ok = data.rgb_valid & np.all(np.isfinite(true), -1)
    assert np.abs(true[ok]).mean() > 1.0  # not vacuous: the image moves by ~1.5 px
    assert np.abs(true[ok] - est[ok]).mean() < 0.3 * np.abs(true[ok]).mean()  # measured 0.19


def test_camera_effects_need_their_inputs():
    sparse, dense = residual_data("door"), residual_data("door", **DENSE)
    # Poses 0.27 s apart cannot tell the velocity through ~6 Hz hand shake; 1/30 s apart can.
    for effect in (TimeOffset(), RollingShutter()):
        assert not effect.applies(sparse) and effect.applies(dense)
    assert PoseDrift().applies(sparse) and LensDistortion().applies(sparse)
    bare = replace(sparse, world_from_camera=None, depth_intrinsics=None)
    assert not PoseDrift().applies(bare) and not TimeOffset().applies(bare)


def test_bad_poses_or_intrinsics_are_input_errors():
    depth = np.ones((3, 4, 4), np.float32)
    with pytest.raises(InputError, match="world_from_camera"):
        make_residual_data(depth_pred=depth, depth_meas=depth, world_from_camera=np.eye(4))
    with pytest.raises(InputError, match="depth_intrinsics"):
        make_residual_data(depth_pred=depth, depth_meas=depth, depth_intrinsics=np.ones((2, 4)))
    with pytest.raises(InputError, match="timestamps"):
        make_residual_data(depth_pred=depth, depth_meas=depth, timestamps=np.arange(4.0))
    ok = make_residual_data(depth_pred=depth, depth_meas=depth, depth_intrinsics=np.ones(4),
                            world_from_camera=np.tile(np.eye(4), (3, 1, 1)), timestamps=np.arange(3.0))
    assert ok.depth_intrinsics.shape == (3, 4) and ok.has_poses
