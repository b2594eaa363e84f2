"""One Adam step for every trainer, with an optional row mask (gsplat's ``SelectiveAdam``).

The trainers keep their Adam moments next to their parameters (so a state can be checkpointed
and resumed) and call :func:`adam_step` once per parameter tensor per step. A row mask limits the
step to some rows, e.g. the Gaussians that may change in a phase, or those visible in the view:
the other rows keep their values AND their moments, as if the step had not happened to them.
"""

from __future__ import annotations

import torch

ADAM_BETAS = (0.9, 0.999)
ADAM_EPS = 1e-15  # as the 3DGS reference code: Gaussians' gradients are tiny


@torch.no_grad()
def adam_step(
    param: torch.Tensor,
    exp_avg: torch.Tensor,
    exp_avg_sq: torch.Tensor,
    lr: float,
    step: int,
    rows: torch.Tensor | None = None,
    betas: tuple[float, float] = ADAM_BETAS,
    eps: float = ADAM_EPS,
) -> None:
    """One Adam step on ``param`` from ``param.grad``, in place (nothing happens without a gradient).

    Args:
        param: ``[N, ...]`` leaf tensor with ``.grad``.
        exp_avg, exp_avg_sq: ``[N, ...]`` its first and second moments, updated in place.
        lr: learning rate (per step, in the parameter's units).
        step: 1-based number of this step, for the bias correction (the trainer's global count,
            also for rows a mask skipped before).
        rows: ``[N]`` bool, on ``param``'s device: only these rows update their moments and
            values (None: every row).
        betas, eps: Adam's constants.
    """
    g = param.grad
    if g is None:
        return
    b1, b2 = betas
    bc1, bc2 = 1 - b1**step, 1 - b2**step
    if rows is None:
        exp_avg.mul_(b1).add_(g, alpha=1 - b1)
        exp_avg_sq.mul_(b2).addcmul_(g, g, value=1 - b2)
        param.sub_(lr * (exp_avg / bc1) / ((exp_avg_sq / bc2).sqrt() + eps))
        return
    # The same arithmetic on every row, then kept only on ``rows``: the selected rows come out
    # bit-identical to the unmasked step, and no boolean indexing means no host sync on a GPU.
    keep = rows.view(-1, *([1] * (param.dim() - 1)))
    m = exp_avg.mul(b1).add_(g, alpha=1 - b1)
    v = exp_avg_sq.mul(b2).addcmul_(g, g, value=1 - b2)
    upd = lr * (m / bc1) / ((v / bc2).sqrt() + eps)
    exp_avg.copy_(torch.where(keep, m, exp_avg))
    exp_avg_sq.copy_(torch.where(keep, v, exp_avg_sq))
    param.sub_(torch.where(keep, upd, 0.0))
