"""Row edits of a Gaussian model together with its optimiser state (gsplat's ``strategy/ops.py``).

Densification, pruning and seeding all come down to: keep some rows of every parameter, append
new ones. The optimiser's moments must follow the same rows, and new rows start with zero moments
(3DGS's ``cat_tensors_to_optimizer`` / ``_prune_optimizer``).
"""

from __future__ import annotations

from collections.abc import Mapping, Sequence

import torch


@torch.no_grad()
def edit_rows(
    params: dict[str, torch.Tensor],
    moments: Sequence[dict[str, torch.Tensor]],
    keep: torch.Tensor,
    new: Mapping[str, torch.Tensor] | None = None,
) -> None:
    """Keep rows ``keep`` of every parameter and of its moments, then append ``new`` rows.

    Args:
        params: name -> ``[N, ...]`` leaf tensor; replaced in place by fresh contiguous leaf
            tensors that require grad (their ``.grad`` is gone).
        moments: optimiser state dicts shaped as ``params`` (Adam's ``exp_avg``, ``exp_avg_sq``);
            their rows follow the parameters', the appended rows are zero.
        keep: ``[N]`` bool (or an index tensor) on the parameters' device.
        new: name -> ``[M, ...]`` rows to append, every name of ``params``, same trailing shapes,
            dtype and device (None: append nothing).
    """
    for name in list(params):
        p = params[name].detach()[keep]
        kept = [m[name][keep] for m in moments]
        if new is not None:
            extra = new[name]
            p = torch.cat([p, extra])
            kept = [torch.cat([m, torch.zeros_like(extra)]) for m in kept]
        params[name] = p.contiguous().requires_grad_(True)
        for m, k in zip(moments, kept, strict=True):
            m[name] = k.contiguous()
