"""compare_runs on hand-made runs: directions, the training / held-out / worst-frame split, errors."""

from __future__ import annotations

import numpy as np
import pytest

from artitwin_core import InputError
from artitwin_core.diagnostics import RunRecord, compare_runs, comparison_html
from artitwin_core.diagnostics._runs import better_direction


def test_better_direction_of_metric_names():
    assert better_direction("reconstruct_report/heldout_psnr_db") == 1
    assert better_direction("reconstruct_report/heldout_ssim") == 1
    assert better_direction("reconstruct_report/heldout_depth_mae_m") == -1
    assert better_direction("diagnose/static recording/photometric_energy_before") == -1
    assert better_direction("diagnose/static recording/photometric_energy_after") == 0  # a what-if, not the twin
    assert better_direction("diagnose/static recording/photometric_energy_floor") == 0
    assert better_direction("reconstruct_report/gaussians_count") == 0
    assert better_direction("reconstruct_report/pose_correction_max_m") == 0


def test_curves_split_into_training_heldout_and_worst_frames():
    # Run A has a bad stretch (frames 8..11); B fixes it and halves the held-out error (0, 4, 8, 12).
    a = np.full(16, 0.02)
    a[8:12] = 0.10
    b = np.full(16, 0.02)
    b[[0, 4, 8, 12]] = 0.01
    curve = "diagnose/static recording/rgb_rms"
    held = [0, 4, 8, 12]
    ra = RunRecord("A", [], {"x/heldout_psnr_db": 24.0, "x/depth_mae_m": 0.02}, {curve: a.tolist()}, {curve: held})
    rb = RunRecord("B", ["exposure_white_balance"], {"x/heldout_psnr_db": 27.0, "x/depth_mae_m": 0.03},
                   {curve: b.tolist()}, {curve: held})
    cmp = compare_runs(ra, rb)
    psnr = next(m for m in cmp.metrics if m.name == "x/heldout_psnr_db")
    depth = next(m for m in cmp.metrics if m.name == "x/depth_mae_m")
    assert psnr.improved and not depth.improved
    (c,) = cmp.curves
    assert c.worst_frames == [8, 9, 10, 11]
    assert c.worst_a == pytest.approx(0.10) and c.worst_b == pytest.approx(0.0175)
    assert c.rest_a == pytest.approx(0.02) and c.rest_b == pytest.approx(np.mean(np.r_[b[:8], b[12:]]))
    assert c.heldout_a == pytest.approx(np.mean(a[held])) and c.heldout_b == pytest.approx(0.01)
    train = [f for f in range(16) if f not in held]
    assert c.train_a == pytest.approx(np.mean(a[train])) and c.train_b == pytest.approx(0.02)
    assert "B models exposure_white_balance" in cmp.conclusion[0]
    assert "1 of 2 metrics improved, 1 got worse." in cmp.conclusion
    html = comparison_html(cmp)
    assert html.count("<svg") == 1 and "worse" in html and "better" in html


def test_runs_of_different_captures_are_refused():
    ra = RunRecord("A", per_frame={"d/c_rms": [1.0, 2.0]})
    rb = RunRecord("B", per_frame={"d/c_rms": [1.0, 2.0, 3.0]})
    with pytest.raises(InputError, match="same scene"):
        compare_runs(ra, rb)
