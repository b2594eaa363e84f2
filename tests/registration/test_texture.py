"""The texture test of a registration: surfaces, within-surface correlation, and when it refuses."""

from __future__ import annotations

import numpy as np

from artitwin_core.registration import HypothesisScore, RegistrationConfig
from artitwin_core.registration._register import _texture_refusal
from artitwin_core.registration._texture import surface_groups, within_surface_correlation

UP = np.array([0.0, 1.0, 0.0])


def _plane(rng, n: int, axis: int, offset: float, normal_sign_flips: bool = True):
    """``n`` points on the plane ``x[axis] = offset`` (a 2 m square) and their normals, signs random."""
    pts = rng.uniform(-1.0, 1.0, (n, 3))
    pts[:, axis] = offset
    normals = np.zeros((n, 3))
    normals[:, axis] = rng.choice([-1.0, 1.0], n) if normal_sign_flips else 1.0
    return pts, normals


def test_surface_groups_tell_planes_apart_whatever_the_normal_sign():
    rng = np.random.default_rng(0)
    planes = [_plane(rng, 200, 1, 0.0), _plane(rng, 200, 1, 0.8),  # floor, table top
              _plane(rng, 200, 2, -2.0), _plane(rng, 200, 2, -1.5),  # back wall, cabinet front before it
              _plane(rng, 200, 0, -2.3)]  # left wall
    labels = [surface_groups(p, n, UP) for p, n in planes]
    assert all(len(np.unique(g)) == 1 for g in labels)
    assert len({int(g[0]) for g in labels}) == len(planes)


def test_within_surface_correlation():
    rng = np.random.default_rng(1)
    n = 4000
    groups = rng.integers(0, 3, n)
    surface_mean = np.array([0.2, 0.5, 0.8])[groups]  # a dark floor, light walls: the same wherever matched
    texture = 0.05 * rng.standard_normal(n)
    static = surface_mean + texture
    # The same texture under another exposure and offset, with a little noise: agrees.
    same = within_surface_correlation(1.6 * static + 0.1 + 0.005 * rng.standard_normal(n), static, groups)
    assert same is not None and same[0] > 0.95 and abs(same[1] - 0.05) < 0.005
    # Another surface's texture on the same layout of surfaces: the surface means alone must not agree.
    other = within_surface_correlation(surface_mean + 0.05 * rng.standard_normal(n), static, groups)
    assert other is not None and abs(other[0]) < 0.06  # 3 standard errors at n = 4000
    # Plain surfaces, or too few matches: nothing to tell.
    assert within_surface_correlation(surface_mean + 0.01, surface_mean, groups) is None
    assert within_surface_correlation(static[:10], static[:10], groups[:10]) is None


def _score(agreement: float, contrast: float) -> HypothesisScore:
    return HypothesisScore("yaw sweep 78 deg", np.eye(4), support=0.64, overlap=0.61, inlier_ratio=1.0,
                           constraint=0.09, colour_agreement=agreement, colour_contrast=contrast)


def test_texture_refusal_needs_texture_that_disagrees():
    cfg = RegistrationConfig()
    failed = _texture_refusal(_score(-0.05, 0.052), cfg)
    assert len(failed) == 1 and "-0.05" in failed[0] and "0.052" in failed[0] and "min_colour_agreement 0.2" in failed[0]
    assert _texture_refusal(_score(0.6, 0.052), cfg) == []  # the right placement: 0.4-0.9 measured
    assert _texture_refusal(_score(-0.05, 0.01), cfg) == []  # plain surfaces: the correlation is noise
    assert _texture_refusal(_score(float("nan"), 0.0), cfg) == []  # no frame had texture to compare
