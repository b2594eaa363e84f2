"""A twin made from a synthetic scene's ground truth, for tests, benchmarks and demos without a run.

Clean renders of the closed scene from a few static-recording viewpoints are back-projected into
one small isotropic Gaussian per pixel, coloured by the render and labelled by the true part mask;
the joints are the true joints. No optimisation, so it is cheap and its geometry is exact.
"""

from __future__ import annotations

import numpy as np

from artitwin_core.gaussians import LABEL_BACKGROUND, LABEL_PART, GaussianParams
from artitwin_core.geometry import backproject
from artitwin_core.viewer._splats import SH_C0
from artitwin_core.viewer._twin import CameraRig, TwinData


def synthetic_twin(
    scene,
    *,
    num_views: int = 4,
    width: int = 128,
    height: int = 96,
    max_gaussians: int | None = None,
    seed: int = 0,
) -> TwinData:
    """A ``TwinData`` from ``scene`` (a ``synth.SyntheticScene``) at its closed state.

    Args:
        num_views: static-recording frames rendered (evenly spaced).
        width, height: render size in pixels; one Gaussian per pixel with a depth.
        max_gaussians: random subsample to at most this many (None keeps all).
        seed: for the subsample.
    """
    from artitwin_core.synth import render_state  # renders with numba: import on use only

    truth = scene.truth
    poses_all = truth.static_world_from_camera
    idx = np.linspace(0, poses_all.shape[0] - 1, num_views).round().astype(int)
    src_h, src_w = scene.static.rgb.shape[1:3]
    kscale = np.array([width / src_w, height / src_h, width / src_w, height / src_h])
    pts, cols, labs, sizes = [], [], [], []
    intrinsics = []
    for i in idx:
        fx, fy, cx, cy = np.asarray(scene.static.rgb_intrinsics[i], np.float64) * kscale
        intrinsics.append([fx, fy, cx, cy])
        rgb, depth, mask = render_state(scene, poses_all[i], (fx, fy, cx, cy), width, height, q=[0.0] * len(truth.joints))
        v, u = np.nonzero(np.isfinite(depth) & (depth > 0))
        z = depth[v, u].astype(np.float64)
        cam = backproject(z, (fx, fy, cx, cy), u, v)
        pts.append(cam @ poses_all[i][:3, :3].T + poses_all[i][:3, 3])
        cols.append(rgb[v, u] / 255.0)
        m = mask[v, u].astype(np.int32)
        labs.append(np.where(m > 0, LABEL_PART + m - 1, LABEL_BACKGROUND))
        sizes.append(0.7 * z / fx)  # about one pixel's footprint: neighbouring splats just overlap
    means = np.concatenate(pts)
    keep = np.arange(means.shape[0])
    if max_gaussians is not None and keep.shape[0] > max_gaussians:
        keep = np.sort(np.random.default_rng(seed).choice(keep.shape[0], max_gaussians, replace=False))
    n = keep.shape[0]
    sh = ((np.concatenate(cols)[keep] - 0.5) / SH_C0)[:, None, :]
    params = GaussianParams(
        means=means[keep].astype(np.float32),
        quats_wxyz=np.tile(np.array([1.0, 0, 0, 0], np.float32), (n, 1)),
        log_scales=np.repeat(np.log(np.concatenate(sizes)[keep])[:, None], 3, 1).astype(np.float32),
        opacity_logits=np.full(n, 4.0, np.float32),
        sh=sh.astype(np.float32),
        labels=np.concatenate(labs)[keep].astype(np.int32),
    )
    cameras = CameraRig(poses_all, np.tile(np.asarray(scene.static.rgb_intrinsics[0], np.float64), (poses_all.shape[0], 1)),
                        int(src_w), int(src_h))
    names = tuple(f"{j.joint_type}_{k}" for k, j in enumerate(truth.joints))
    return TwinData(params, tuple(truth.joints), names, cameras, title=f"synthetic {scene.spec.furniture}")
