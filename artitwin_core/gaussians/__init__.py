"""3D Gaussian splatting: parameters, rasterization (CPU and CUDA backends), densification."""

from artitwin_core.gaussians._device import Backend, BackendName, resolve_backend
from artitwin_core.gaussians._rasterize import RenderOutput, rasterize
from artitwin_core.gaussians._sh import eval_sh_colors, num_sh_bases
from artitwin_core.gaussians._types import (
    LABEL_BACKGROUND,
    LABEL_INTERIOR,
    LABEL_PART,
    GaussianParams,
)

__all__ = [
    "Backend",
    "BackendName",
    "LABEL_BACKGROUND",
    "LABEL_INTERIOR",
    "LABEL_PART",
    "GaussianParams",
    "RenderOutput",
    "eval_sh_colors",
    "num_sh_bases",
    "rasterize",
    "resolve_backend",
]
