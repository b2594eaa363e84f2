"""The in-memory parameters of a 3D Gaussian splatting model."""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

# Part labels of each Gaussian (articulation splits the model; 0 until then).
LABEL_BACKGROUND = 0
LABEL_INTERIOR = 1
LABEL_PART = 2  # part k is LABEL_PART + k


@dataclass(frozen=True)
class GaussianParams:
    """Parameters of N Gaussians in the canonical world frame, in the 3DGS parameterisation.

    Attributes:
        means: ``[N, 3]`` float32 centres, metres.
        quats_wxyz: ``[N, 4]`` float32 rotations, scalar-first (need not be normalised).
        log_scales: ``[N, 3]`` float32 natural log of per-axis standard deviations in metres.
        opacity_logits: ``[N]`` float32 logit of opacity.
        sh: ``[N, K, 3]`` float32 spherical-harmonic colour coefficients, K = (degree + 1)^2;
            ``sh[:, 0]`` is the DC term (colour = 0.5 + C0 * sh_dc before clamping).
        labels: ``[N]`` int32 part labels (``LABEL_BACKGROUND``, ``LABEL_INTERIOR``, ``LABEL_PART + k``).
    """

    means: np.ndarray
    quats_wxyz: np.ndarray
    log_scales: np.ndarray
    opacity_logits: np.ndarray
    sh: np.ndarray
    labels: np.ndarray

    @property
    def num_gaussians(self) -> int:
        return int(self.means.shape[0])

    @property
    def sh_degree(self) -> int:
        return int(round(np.sqrt(self.sh.shape[1]))) - 1
