"""How a part's brightness changes with its joint state: one gain curve per part.

A part that turns changes its angle to the light: under the synthetic scenes' point light the
front of a door opened by 1.2 rad is 2.7 times darker than when closed. Colours baked into the
Gaussians cannot follow that, and the static recording (parts closed) pins them to the closed
shading. Each part k therefore gets a gain ``g_k(q)`` on the colour of its Gaussians, piecewise
linear in log space between ``M`` knots over the trained joint range and held constant outside
it, with ``g_k(0) = 1`` exactly (the closed state is what the static recording shows). The gain
is one scalar (not per channel): white light scales every channel of a Lambertian surface alike,
and the sRGB encoding keeps a scalar gain scalar.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np
import torch

from artitwin_core._errors import InputError
from artitwin_core.gaussians import LABEL_PART
from artitwin_core.gaussians._sh import SH_C0


@dataclass(frozen=True)
class PartAppearance:
    """Per-part brightness as a function of the joint state.

    Attributes:
        knots: ``[K, M]`` float64 ascending joint states (radians or metres) per part.
        log_gain: ``[K, M]`` float64 natural log of the gain at the knots, before pinning the
            closed state (the gain at q is ``exp(interp(q) - interp(0))``).
    """

    knots: np.ndarray
    log_gain: np.ndarray

    def __post_init__(self) -> None:
        if self.knots.shape != self.log_gain.shape or self.knots.ndim != 2:
            raise InputError(
                f"PartAppearance: knots {self.knots.shape} and log_gain {self.log_gain.shape} must both be [K, M]."
            )
        if self.knots.shape[1] >= 2 and np.any(np.diff(self.knots, axis=1) <= 0):
            raise InputError("PartAppearance: knots must be strictly ascending per part.")

    @classmethod
    def neutral(cls, q_per_joint: np.ndarray, num_knots: int) -> PartAppearance:
        """Gain 1 everywhere, ``num_knots`` knots over ``[min(q, 0), max(q, 0)]`` of ``q_per_joint [T, K]``."""
        q = np.asarray(q_per_joint, np.float64).reshape(len(q_per_joint), -1)
        k = q.shape[1]
        knots = np.zeros((k, num_knots))
        for j in range(k):
            lo, hi = min(float(q[:, j].min(initial=0.0)), 0.0), max(float(q[:, j].max(initial=0.0)), 0.0)
            if hi - lo < 1e-9:
                hi = lo + 1e-3
            knots[j] = np.linspace(lo, hi, num_knots)
        return cls(knots=knots, log_gain=np.zeros((k, num_knots)))

    @property
    def num_parts(self) -> int:
        return int(self.knots.shape[0])

    def gains(self, q_per_joint: Sequence[float]) -> np.ndarray:
        """``[K]`` gain of each part at joint states ``q_per_joint [K]``."""
        g = part_log_gains(torch.from_numpy(self.log_gain), self.knots, q_per_joint)
        return np.exp(g.detach().numpy())


def _interp_weights(knots: np.ndarray, q: float) -> np.ndarray:
    """``[M]`` linear-interpolation weights of ``q`` on ``knots [M]`` (clamped at the ends)."""
    w = np.zeros(len(knots))
    if len(knots) == 1 or q <= knots[0]:
        w[0] = 1.0
    elif q >= knots[-1]:
        w[-1] = 1.0
    else:
        i = int(np.searchsorted(knots, q, side="right")) - 1
        f = (q - knots[i]) / (knots[i + 1] - knots[i])
        w[i], w[i + 1] = 1.0 - f, f
    return w


def part_log_gains(log_gain: torch.Tensor, knots: np.ndarray, q_per_joint: Sequence[float]) -> torch.Tensor:
    """``[K]`` log gain of each part at ``q_per_joint [K]``, pinned to 0 at q = 0 (differentiable
    in ``log_gain [K, M]``)."""
    out = []
    for k in range(log_gain.shape[0]):
        w = _interp_weights(knots[k], float(q_per_joint[k])) - _interp_weights(knots[k], 0.0)
        out.append((log_gain[k] * torch.as_tensor(w, dtype=log_gain.dtype, device=log_gain.device)).sum())
    return torch.stack(out) if out else log_gain.new_zeros(0)


def apply_part_gains(sh: torch.Tensor, labels: torch.Tensor, log_gains: torch.Tensor) -> torch.Tensor:
    """``sh [N, C, 3]`` with the colour of every part-k Gaussian multiplied by ``exp(log_gains[k])``.

    The rendered colour is ``0.5 + SH(d)``; scaling it by g scales every coefficient by g and
    adds ``(g - 1) 0.5 / C0`` to the DC term.
    """
    k = int(log_gains.shape[0])
    if k == 0:
        return sh
    table = torch.cat([log_gains.new_zeros(LABEL_PART), log_gains]).to(sh.dtype)
    idx = labels.long().clamp(0, LABEL_PART + k - 1)
    idx = torch.where(labels.long() >= LABEL_PART + k, 0, idx)
    g = torch.exp(table[idx])
    dc = sh[:, :1] * g[:, None, None] + ((g - 1.0) * (0.5 / SH_C0))[:, None, None]
    return torch.cat([dc, sh[:, 1:] * g[:, None, None]], 1)
