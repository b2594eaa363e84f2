"""3D Gaussian splatting: parameters, rasterization (CPU and CUDA backends), and what every trainer
shares: one Adam step (with a row mask), one row edit, the densification strategy."""

from artitwin_core.gaussians._device import Backend, BackendName, resolve_backend
from artitwin_core.gaussians._ops import edit_rows
from artitwin_core.gaussians._optim import ADAM_BETAS, ADAM_EPS, adam_step
from artitwin_core.gaussians._rasterize import RenderOutput, rasterize
from artitwin_core.gaussians._sh import eval_sh_colors, num_sh_bases
from artitwin_core.gaussians._strategy import DensifiableState, DensifyStrategy
from artitwin_core.gaussians._types import (
    LABEL_BACKGROUND,
    LABEL_INTERIOR,
    LABEL_PART,
    GaussianParams,
)

__all__ = [
    "ADAM_BETAS",
    "ADAM_EPS",
    "Backend",
    "BackendName",
    "DensifiableState",
    "DensifyStrategy",
    "LABEL_BACKGROUND",
    "LABEL_INTERIOR",
    "LABEL_PART",
    "GaussianParams",
    "RenderOutput",
    "adam_step",
    "edit_rows",
    "eval_sh_colors",
    "num_sh_bases",
    "rasterize",
    "resolve_backend",
]
