"""Per-part 3DGS .ply export: each label's Gaussians round-trip through the standard reader."""

from __future__ import annotations

import numpy as np

from artitwin_core.export import export_part_plys
from artitwin_core.gaussians import GaussianParams
from artitwin_core.reconstruction import read_ply


def _params(n: int, seed: int = 0) -> GaussianParams:
    rng = np.random.default_rng(seed)
    return GaussianParams(
        means=rng.normal(size=(n, 3)).astype(np.float32),
        quats_wxyz=rng.normal(size=(n, 4)).astype(np.float32),
        log_scales=rng.normal(-4, 1, size=(n, 3)).astype(np.float32),
        opacity_logits=rng.normal(size=n).astype(np.float32),
        sh=rng.normal(size=(n, 16, 3)).astype(np.float32),
        labels=rng.choice([0, 1, 2, 3], size=n).astype(np.int32),  # background, interior, parts 0 and 1
    )


def test_split_by_label_round_trips(tmp_path):
    params = _params(500)
    pivot1 = np.array([0.4, 0.45, 0.0])
    files = export_part_plys(params, tmp_path, part_names=["../door 1", "door 1"], pivots=[np.zeros(3), pivot1])
    assert sorted(files) == ["background", "door_1", "door_1_2", "interior"]
    total = 0
    for name, label, shift in [("background", 0, 0.0), ("interior", 1, 0.0), ("door_1", 2, 0.0),
                               ("door_1_2", 3, pivot1)]:
        keep = params.labels == label
        back = read_ply(files[name])
        total += back.num_gaussians
        # float32 written and read bit-exactly; the pivot shift is one float32 subtraction.
        np.testing.assert_allclose(back.means, params.means[keep] - shift, atol=1e-6)
        np.testing.assert_array_equal(back.sh, params.sh[keep])
        np.testing.assert_array_equal(back.quats_wxyz, params.quats_wxyz[keep])
        np.testing.assert_array_equal(back.log_scales, params.log_scales[keep])
        np.testing.assert_array_equal(back.opacity_logits, params.opacity_logits[keep])
    assert total == params.num_gaussians
