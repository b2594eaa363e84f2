"""Training lowers the loss, reaches a stated held-out PSNR on the tiny scene, densifies as 3DGS
does, and resumes from a stored state to the same result."""

from __future__ import annotations

import copy

import numpy as np
import pytest
import torch

from artitwin_core.reconstruction import (
    InitConfig,
    TrainConfig,
    TrainState,
    evaluate_views,
    init_gaussians,
    make_views,
    scene_extent,
    split_frames,
    train,
)
from artitwin_core.reconstruction._train import densify_and_prune, reset_opacity

STEPS = 100


@pytest.fixture(scope="module")
def trained(tiny_scene, tiny_gt_depth):
    cap = tiny_scene.static
    train_f, test_f = split_frames(cap.num_frames, 8)
    g0 = init_gaussians(cap, cap.world_from_camera, train_f, InitConfig(max_points=8000))
    views = make_views(cap, cap.world_from_camera, train_f)
    cfg = TrainConfig.with_schedule(STEPS, max_gaussians=16_000)
    state = TrainState.from_params(g0, scene_extent(cap.world_from_camera[train_f]))
    before = evaluate_views(g0, cap, cap.world_from_camera, test_f, gt_depth=tiny_gt_depth)
    train(state, views, cfg)
    after = evaluate_views(state.to_params(), cap, cap.world_from_camera, test_f, gt_depth=tiny_gt_depth)
    return state, before, after, g0


def test_training_lowers_loss_and_improves_heldout_views(trained):
    state, before, after, g0 = trained
    losses = np.asarray(state.losses)
    assert state.step == STEPS and len(losses) == STEPS
    # Measured: first 20 steps ~0.10, last 20 ~0.04 (150 steps, tiny scene).
    assert losses[-20:].mean() < 0.6 * losses[:20].mean(), (losses[:20].mean(), losses[-20:].mean())
    b, a = before.summary(), after.summary()
    # Measured: seeds alone ~21 dB; after 150 steps ~25 dB on the two held-out frames
    # (the 128x96 tiny scene; the 28 dB target is for the 256x192 benchmark scenes, see bench/).
    assert a["psnr_db"] > b["psnr_db"] + 2.0, (b, a)
    assert a["psnr_db"] > 23.0, a
    assert a["ssim"] > b["ssim"]
    # Depth: measured ~2 cm against the ground truth after 150 steps (sensor noise 0.7-3 cm here).
    assert a["depth_mae_gt_m"] < 0.03, a
    assert state.num_gaussians != g0.num_gaussians  # densification/pruning ran


def test_resume_from_a_copied_state_matches_an_uninterrupted_run(tiny_scene):
    cap = tiny_scene.static
    train_f, _ = split_frames(cap.num_frames, 8)
    g0 = init_gaussians(cap, cap.world_from_camera, train_f, InitConfig(max_points=3000))
    views = make_views(cap, cap.world_from_camera, train_f)
    cfg = TrainConfig.with_schedule(24, densify_from=6, densify_every=6, densify_until=18)
    ext = scene_extent(cap.world_from_camera[train_f])
    straight = train(TrainState.from_params(g0, ext), views, cfg)
    first = train(TrainState.from_params(g0, ext), views, cfg, until=12)
    resumed = train(copy.deepcopy(first), views, cfg)
    assert resumed.step == straight.step == 24
    a, b = straight.to_params(), resumed.to_params()
    assert a.num_gaussians == b.num_gaussians
    # Same ops in the same order; the CPU rasterizer's backward sums in a fixed order, so the
    # two runs agree to float32 round-off (measured max |diff| 0 to 1e-6 m).
    np.testing.assert_allclose(a.means, b.means, atol=1e-5)
    np.testing.assert_allclose(a.sh, b.sh, atol=1e-4)


def _toy_state(n: int = 4, scale: float = 0.01) -> TrainState:
    from artitwin_core.gaussians import GaussianParams

    params = GaussianParams(
        means=np.arange(3 * n, dtype=np.float32).reshape(n, 3),
        quats_wxyz=np.tile(np.array([1, 0, 0, 0], np.float32), (n, 1)),
        log_scales=np.full((n, 3), np.log(scale), np.float32),
        opacity_logits=np.zeros(n, np.float32),
        sh=np.zeros((n, 16, 3), np.float32),
        labels=np.zeros(n, np.int32),
    )
    return TrainState.from_params(params, extent=1.0)


def test_densify_clones_small_splits_large_and_prunes_faint():
    cfg = TrainConfig(percent_dense=0.01, grad_threshold=2e-4)
    st = _toy_state(4, scale=0.005)  # smaller than 1 % of the 1 m extent: clone
    st.params["log_scales"].data[1] = float(np.log(0.05))  # larger: split
    st.params["opacity_logits"].data[3] = -10.0  # opacity 4.5e-5: pruned
    st.grad_accum[:] = torch.tensor([1e-3, 1e-3, 1e-5, 0.0])
    st.grad_count[:] = 1
    stats = densify_and_prune(st, cfg)
    assert stats == {"cloned": 1, "split": 1, "pruned": 1}
    # 4 - 1 split original - 1 pruned + 1 clone + 2 split children = 5
    assert st.num_gaussians == 5
    scales = st.params["log_scales"].detach().exp()[:, 0].numpy()
    np.testing.assert_allclose(np.sort(scales)[-2:], [0.05 / 1.6] * 2, rtol=1e-5)
    assert all(v.shape[0] == 5 for v in st.exp_avg.values())
    assert float(st.grad_accum.sum()) == 0.0  # statistics restart after densifying


def test_opacity_reset_caps_opacity():
    st = _toy_state(3)
    st.params["opacity_logits"].data[:] = torch.tensor([5.0, 0.0, -6.0])
    reset_opacity(st, TrainConfig(opacity_reset_value=0.01))
    op = torch.sigmoid(st.params["opacity_logits"].detach()).numpy()
    np.testing.assert_allclose(op[:2], [0.01, 0.01], rtol=1e-5)
    assert op[2] < 0.01
