"""Which rasterizer backend and torch device a config's ``backend`` names.

Every trainer and renderer above the rasterizer resolves its config's ``backend`` here once and
creates its tensors on the device it returns, so a run with a GPU keeps everything on it and one
without never touches CUDA. ``"auto"`` is CUDA with gsplat when both are present, else the CPU.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Literal, get_args

import torch

from artitwin_core._errors import InputError
from artitwin_core.gaussians._raster_cuda import gsplat_available

BackendName = Literal["auto", "cpu", "reference", "cuda"]
_NAMES: tuple[BackendName, ...] = get_args(BackendName)


@dataclass(frozen=True)
class Backend:
    """A resolved backend: ``name`` is ``"cpu"``, ``"reference"`` or ``"cuda"`` (never ``"auto"``),
    ``device`` the torch device its tensors live on."""

    name: str
    device: torch.device

    @property
    def is_cuda(self) -> bool:
        return self.device.type == "cuda"


def resolve_backend(backend: BackendName = "auto") -> Backend:
    """The backend and device for a config's ``backend`` (``auto``, ``cpu``, ``reference``, ``cuda``).

    ``"cuda"`` without a CUDA device or without gsplat raises :class:`InputError` saying what is
    missing; ``"auto"`` then falls back to the CPU.
    """
    if backend not in _NAMES:
        raise InputError(f"backend {backend!r} is not one of {_NAMES}.")
    if backend == "auto":
        backend = "cuda" if gsplat_available() else "cpu"
    if backend == "cuda":
        if not torch.cuda.is_available():
            raise InputError("backend 'cuda' needs a CUDA device and none is visible; use backend 'auto' or 'cpu'.")
        if not gsplat_available():
            raise InputError("backend 'cuda' needs the gsplat package (pip install gsplat); use backend 'auto' or 'cpu'.")
        return Backend("cuda", torch.device("cuda", torch.cuda.current_device()))
    return Backend(backend, torch.device("cpu"))
