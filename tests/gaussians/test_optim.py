"""The shared Adam step and row edit: torch.optim.Adam on unmasked rows, masked rows untouched
(gsplat's SelectiveAdam), and optimiser rows following the parameters through an edit."""

from __future__ import annotations

import torch

from artitwin_core.gaussians import ADAM_BETAS, ADAM_EPS, DensifyStrategy, adam_step, edit_rows


def _grads(steps: int, shape, seed: int = 0) -> list[torch.Tensor]:
    g = torch.Generator().manual_seed(seed)
    return [torch.randn(shape, generator=g, dtype=torch.float64) for _ in range(steps)]


def test_adam_step_matches_torch_adam():
    p0 = torch.randn(6, 3, dtype=torch.float64)
    ours = p0.clone().requires_grad_(True)
    ref = p0.clone().requires_grad_(True)
    opt = torch.optim.Adam([ref], lr=0.01, betas=ADAM_BETAS, eps=ADAM_EPS)
    m, v = torch.zeros_like(p0), torch.zeros_like(p0)
    for t, g in enumerate(_grads(20, p0.shape), start=1):
        ours.grad, ref.grad = g.clone(), g.clone()
        adam_step(ours, m, v, 0.01, t)
        opt.step()
    # torch divides by sqrt(v_hat) the same way; measured max |diff| 1e-17 (float64 round-off).
    torch.testing.assert_close(ours.detach(), ref.detach(), rtol=0, atol=1e-12)
    torch.testing.assert_close(m, opt.state[ref]["exp_avg"], rtol=0, atol=1e-12)
    torch.testing.assert_close(v, opt.state[ref]["exp_avg_sq"], rtol=0, atol=1e-12)


def test_masked_rows_keep_values_and_moments_and_the_rest_step_as_unmasked():
    p0 = torch.randn(5, 2, 3, dtype=torch.float64)
    rows = torch.tensor([True, False, True, True, False])
    full = p0.clone().requires_grad_(True)
    masked = p0.clone().requires_grad_(True)
    mf, vf = torch.full_like(p0, 0.1), torch.full_like(p0, 0.2)
    mm, vm = mf.clone(), vf.clone()
    for t, g in enumerate(_grads(7, p0.shape, seed=1), start=3):
        full.grad, masked.grad = g.clone(), g.clone()
        adam_step(full, mf, vf, 0.05, t)
        adam_step(masked, mm, vm, 0.05, t, rows=rows)
    # Selected rows: the very same arithmetic as the unmasked step.
    assert torch.equal(masked.detach()[rows], full.detach()[rows])
    assert torch.equal(mm[rows], mf[rows]) and torch.equal(vm[rows], vf[rows])
    # Skipped rows: value and moments untouched, not even decayed.
    assert torch.equal(masked.detach()[~rows], p0[~rows])
    assert bool((mm[~rows] == 0.1).all()) and bool((vm[~rows] == 0.2).all())


def test_no_gradient_no_step():
    p = torch.ones(3, requires_grad=True)
    m, v = torch.zeros(3), torch.zeros(3)
    adam_step(p, m, v, 1.0, 1)
    assert torch.equal(p.detach(), torch.ones(3)) and not m.any() and not v.any()


def test_edit_rows_keeps_appends_and_moments_follow():
    params = {"a": torch.arange(8.0).reshape(4, 2).requires_grad_(True), "b": torch.arange(4.0).requires_grad_(True)}
    m1 = {"a": params["a"].detach() + 100, "b": params["b"].detach() + 100}
    m2 = {"a": params["a"].detach() + 200, "b": params["b"].detach() + 200}
    keep = torch.tensor([True, False, True, False])
    new = {"a": torch.full((3, 2), -1.0), "b": torch.full((3,), -2.0)}
    edit_rows(params, (m1, m2), keep, new)
    assert params["a"].tolist() == [[0, 1], [4, 5], [-1, -1], [-1, -1], [-1, -1]]
    assert params["b"].tolist() == [0, 2, -2, -2, -2]
    assert params["a"].is_leaf and params["a"].requires_grad and params["a"].is_contiguous()
    assert m1["a"][:2].tolist() == [[100, 101], [104, 105]] and not m1["a"][2:].any()
    assert m2["b"].tolist() == [200, 202, 0, 0, 0]
    edit_rows(params, (m1, m2), torch.tensor([False, True, True, False, False]))  # prune only
    assert params["b"].tolist() == [2, -2] and m1["b"].tolist() == [102, 0]


def test_the_strategy_edits_moments_with_the_parameters():
    class State:
        pass

    s = State()
    n = 4
    s.params = {
        "means": torch.zeros(n, 3), "quats_wxyz": torch.tensor([[1.0, 0, 0, 0]] * n),
        "log_scales": torch.full((n, 3), -5.0), "opacity_logits": torch.tensor([0.0, 0.0, -10.0, 0.0]),
        "sh_dc": torch.zeros(n, 1, 3), "sh_rest": torch.zeros(n, 0, 3),
    }  # fmt: skip
    s.exp_avg = {k: torch.ones_like(v) for k, v in s.params.items()}
    s.exp_avg_sq = {k: torch.ones_like(v) for k, v in s.params.items()}
    s.step, s.extent = 10, 1.0
    s.grad_accum, s.grad_count, s.max_radii = torch.tensor([1.0, 0, 0, 0]), torch.ones(n), torch.zeros(n)
    strategy = DensifyStrategy(
        densify_from=1, densify_until=100, densify_every=10, grad_threshold=0.5, percent_dense=0.01,
        max_gaussians=100, min_opacity=0.005, max_screen_radius_px=40.0, max_world_scale=0.1,
        opacity_reset_every=0, opacity_reset_value=0.01, seed=0,
    )  # fmt: skip
    assert strategy.densify_and_prune(s) == {"cloned": 1, "split": 0, "pruned": 1}
    # Rows 0, 1, 3 kept with their moments, the clone of row 0 appended with zero moments.
    assert s.params["means"].shape[0] == 4
    assert s.exp_avg["means"][:3].eq(1).all() and not s.exp_avg["means"][3].any()
    assert s.grad_accum.shape == (4,) and not s.grad_accum.any()
