"""Device-generic training: stage I (3DGS) and stage IV (articulation) run the same code on any device.

``train_both`` trains the tiny door's canonical model and then articulates it, on the backend it
is given, from one seed, and returns the loss curves and held-out PSNRs. The CPU tests run it on
the CPU, and once more through the CUDA backend's code path with a stand-in for gsplat (every
tensor on the CPU: it checks the trainers' use of the CUDA adapter, not CUDA). The ``gpu`` test
runs it on CUDA with gsplat and compares with the CPU from the same seed.
"""

from __future__ import annotations

import dataclasses
import sys
import types

import numpy as np
import pytest
import torch

from artitwin_core import InputError
from artitwin_core.articulation import ArticulationConfig, TwinRenderer, articulate
from artitwin_core.gaussians import Backend, resolve_backend
from artitwin_core.masks import MaskSequence
from artitwin_core.reconstruction import (
    InitConfig,
    ModelRenderer,
    PoseRefineConfig,
    ReconstructionConfig,
    TrainConfig,
    reconstruct,
)
from tests.gaussians._fake_gsplat import CALLS, _fake_rasterization


def train_both(
    scene, backend: str, steps: int, phase_steps: tuple[int, int], max_gaussians: int, max_side: tuple = (None, None)
) -> dict:
    """Stage I then stage IV of ``scene`` on ``backend`` (true poses, masks and joints; seed 0), each
    trained at most ``max_side`` pixels on the long side."""
    cap = scene.static
    truth = scene.truth
    static = dataclasses.replace(cap, world_from_camera=truth.static_world_from_camera)
    config = ReconstructionConfig(
        init=InitConfig(max_points=max_gaussians // 2),
        poses=PoseRefineConfig(enabled=False),
        train=TrainConfig.with_schedule(steps, max_gaussians=max_gaussians, backend=backend, max_side=max_side[0]),
    )
    rec = reconstruct(static, config)
    masks = MaskSequence(part=truth.part_masks, hand=truth.hand_masks, score=np.ones(len(truth.part_masks), np.float32))
    result = articulate(
        rec.params, static, static.world_from_camera, scene.dynamic, truth.dynamic_world_from_camera, masks,
        truth.joints,
        ArticulationConfig(phase1_steps=phase_steps[0], phase2_steps=phase_steps[1], backend=backend,
                           seed_max_points=500, seed_background_max_points=500, max_side=max_side[1],
                           appearance_knots=8),
    )  # fmt: skip
    return {"stage_i_losses": rec.losses, "stage_i_psnr": float(rec.evaluation.summary()["psnr_db"]),
            "stage_iv_losses": result.losses, "stage_iv_psnr": result.psnr_holdout_db, "twin": result.params}


def test_auto_resolves_to_the_cpu_without_cuda():
    if torch.cuda.is_available():
        pytest.skip("a CUDA device is present")
    assert resolve_backend("auto") == Backend("cpu", torch.device("cpu"))
    assert resolve_backend("cpu").device.type == "cpu"
    with pytest.raises(InputError, match="CUDA device"):
        resolve_backend("cuda")
    with pytest.raises(InputError, match="not one of"):
        resolve_backend("gpu")


def test_training_runs_on_the_cpu(tiny_scene):
    """On the CPU, at the CPU preset's reduced training resolutions (the tiny scene is 128x96)."""
    out = train_both(tiny_scene, "cpu", steps=24, phase_steps=(8, 4), max_gaussians=2000, max_side=(96, 64))
    for key in ("stage_i_losses", "stage_iv_losses"):
        assert len(out[key]) > 0 and np.isfinite(out[key]).all()
    assert out["stage_i_losses"][-5:].mean() < out["stage_i_losses"][:5].mean()
    assert 8.0 < out["stage_i_psnr"] < 60.0 and 8.0 < out["stage_iv_psnr"] < 60.0


def test_cuda_code_path_without_a_gpu(tiny_scene, monkeypatch):
    """The trainers and renderers on backend 'cuda', everything on the CPU, gsplat a CPU stand-in:
    the arguments they hand the adapter (background and intrinsics on the tensors' device, the
    [1, N, 2] screen-space means whose gradient densification reads) work end to end."""
    import artitwin_core.articulation._pipeline as art_pipeline
    import artitwin_core.reconstruction._evaluate as evaluate_module
    import artitwin_core.reconstruction._pipeline as rec_pipeline
    from artitwin_core.gaussians import _raster_cuda

    monkeypatch.setitem(sys.modules, "gsplat", types.SimpleNamespace(rasterization=_fake_rasterization))
    monkeypatch.setattr(_raster_cuda, "gsplat_available", lambda: True)
    fake = Backend("cuda", torch.device("cpu"))  # the CUDA code path with its tensors on the CPU
    for module in (rec_pipeline, art_pipeline, evaluate_module):
        monkeypatch.setattr(module, "resolve_backend", lambda name, _fake=fake: _fake)
    calls = len(CALLS)
    # The dense stand-in is slow: a few steps on few Gaussians, trained at 64 and 48 pixels on the
    # long side (27 s at the tiny scene's 128x96, 4 s so, on a shared 2-core machine).
    out = train_both(tiny_scene, "cuda", steps=6, phase_steps=(3, 2), max_gaussians=600, max_side=(64, 48))
    assert len(CALLS) > calls + 11  # every render went through the adapter
    assert np.isfinite(out["stage_i_losses"]).all() and np.isfinite(out["stage_iv_losses"]).all()
    assert np.isfinite(out["stage_i_psnr"]) and np.isfinite(out["stage_iv_psnr"])


@pytest.mark.gpu
@pytest.mark.skipif(not torch.cuda.is_available(), reason="needs a CUDA device")
def test_cuda_training_matches_cpu(tiny_scene):
    """A few hundred steps of each stage on CUDA and on the CPU from the same seed.

    The view order is seeded identically; split samples draw from each device's own generator
    and the rasterizers differ in float rounding, so the runs are not identical. Tolerances are
    loose and not yet measured on a GPU (none was lent to the session that wrote this):
    the mean loss of the last 50 steps within 10 % and held-out PSNR within 1 dB, per stage.
    """
    pytest.importorskip("gsplat")
    assert resolve_backend("auto").name == "cuda"
    runs = {b: train_both(tiny_scene, b, steps=300, phase_steps=(150, 80), max_gaussians=8000) for b in ("cpu", "cuda")}
    cpu, gpu = runs["cpu"], runs["cuda"]
    for stage in ("stage_i", "stage_iv"):
        a, b = cpu[f"{stage}_losses"][-50:].mean(), gpu[f"{stage}_losses"][-50:].mean()
        assert abs(a - b) <= 0.1 * a, (stage, a, b)
        assert abs(cpu[f"{stage}_psnr"] - gpu[f"{stage}_psnr"]) <= 1.0, (stage, cpu[f"{stage}_psnr"], gpu[f"{stage}_psnr"])
    # Renders of the same twin on both devices agree (the rasterizers' float rounding only).
    cap = tiny_scene.dynamic
    pose = tiny_scene.truth.dynamic_world_from_camera[-1]
    q = [float(j.q[-1]) for j in tiny_scene.truth.joints]
    outs = [TwinRenderer(gpu["twin"], tiny_scene.truth.joints, backend=b).render(q, pose, cap.rgb_intrinsics[-1],
                                                                                 *cap.rgb_size) for b in ("cpu", "cuda")]
    assert np.abs(outs[0][0] - outs[1][0]).max() < 2e-3
    static = ModelRenderer(gpu["twin"], backend="cuda")
    assert static.means.is_cuda
