"""A camera's vignetting from its own frames (``estimate_vignetting``): the synthetic ``vignetting``
effect darkens each frame by ``1 - strength r^2``; the same surfaces seen at other radii in other
frames give it away, with or without exposure and white balance moving between frames."""

from __future__ import annotations

from dataclasses import replace

import numpy as np
import pytest

from artitwin_core import InputError
from artitwin_core.capture import VignettingConfig, estimate_vignetting
from artitwin_core.synth import BENCHMARK_SCENES, generate_scene

TINY = BENCHMARK_SCENES["tiny"]


def _scene(seed: int, *effects):
    return generate_scene(replace(TINY, seed=seed, static_frames=16, effects=tuple(effects)))


@pytest.fixture(scope="module")
def scenes():
    return {
        "clean": _scene(0),
        "strong": _scene(0, ("vignetting", {"strength": 0.35})),
        # a weaker fall-off under an exposure and white-balance drift, on another seed's scene
        "drifting": _scene(5, ("vignetting", {"strength": 0.2}), ("exposure", {"stops_std": 0.35}),
                           ("white_balance", {"gain_std": 0.06})),
        "exposure only": _scene(7, ("exposure", {"stops_std": 0.35})),
    }


# Measured on these scenes (64 x 48 depth, 128 x 96 RGB): the fall-off within 0.004 of the truth
# in both recordings (the log-quadratic form misses log(1 - 0.35 r^2)'s cubic term by 0.004 at the
# corner), standard errors 0.0005-0.002, and |fall-off| <= 0.001 without vignetting.
@pytest.mark.parametrize(("name", "truth"), [("strong", 0.35), ("drifting", 0.2), ("clean", 0.0), ("exposure only", 0.0)])
@pytest.mark.parametrize("recording", ["static", "dynamic"])
def test_the_fall_off_is_found_in_each_recording_and_none_where_there_is_none(scenes, name, truth, recording):
    capture = getattr(scenes[name], recording)
    est = estimate_vignetting(capture)
    assert est.falloff == pytest.approx(truth, abs=0.01), est
    assert 0 < est.falloff_se < 0.005, est
    # the polynomial form the sensor models take gives the same corner
    assert 1 + est.gain[0] + est.gain[1] == pytest.approx(1 - est.falloff, abs=0.005)
    if truth:
        assert est.residual < 0.6 * est.initial_residual, est  # the fit explains the frames' disagreement
        assert abs(est.falloff) > 20 * est.falloff_se


def test_a_modelled_vignetting_is_divided_out_first(scenes):
    capture = scenes["strong"].static
    assert estimate_vignetting(capture, modelled=(-0.35, 0.0)).falloff == pytest.approx(0.0, abs=0.01)
    half = estimate_vignetting(capture, modelled=(-0.175, 0.0))  # half modelled: the rest is left
    assert 0.14 < half.falloff < 0.23, half


def test_frames_that_share_nothing_are_refused_with_the_reason(scenes):
    capture = scenes["strong"].static
    with pytest.raises(InputError, match="frame pair"):
        estimate_vignetting(capture, config=VignettingConfig(frame_gaps=(40,)))
    with pytest.raises(InputError, match="poses have shape"):
        estimate_vignetting(capture, world_from_camera=np.eye(4)[None])
    with pytest.raises(InputError, match="frame_gaps"):
        VignettingConfig(frame_gaps=(0,))
