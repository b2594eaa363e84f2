"""Every artifact class round-trips exactly through zarr and through the store."""

from __future__ import annotations

import json
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest
import zarr
from zarr.storage import MemoryStore

import schemas
from infra.store import ArtifactStore
from schemas import Artifact, CaptureArtifact, SchemaError, StageReport
from tests.foundation._factories import make_artifact

ALL = schemas.all_artifact_classes()


def test_registry_holds_every_artifact_the_pipeline_passes():
    kinds = {c.kind for c in ALL}
    assert {"capture", "camera_poses", "registration", "mask_sequence", "trajectories", "joint", "joint_set",
            "gaussian_checkpoint", "stage_report"} <= kinds


@pytest.mark.parametrize("cls", ALL, ids=lambda c: c.kind)
def test_every_field_is_described(cls):
    for name, info in cls.model_fields.items():
        assert info.description and len(info.description) > 10, f"{cls.__name__}.{name} needs a description"


@pytest.mark.parametrize("cls", ALL, ids=lambda c: c.kind)
def test_zarr_round_trip_is_exact(cls):
    art = make_artifact(cls, np.random.default_rng(0))
    group = zarr.open_group(MemoryStore(), mode="w")
    art.to_zarr(group)
    back = Artifact.from_zarr(group)
    assert type(back) is cls
    assert back.equals(art)
    # and not trivially: a changed array breaks equality
    specs = cls.array_specs()
    if specs:
        name = next(iter(specs))
        arr = getattr(art, name).copy()
        arr.flat[-1] = arr.flat[-1] + 1 if arr.dtype != np.bool_ else ~arr.flat[-1]
        assert not art.model_copy(update={name: arr}).equals(art)


@pytest.mark.parametrize("cls", ALL, ids=lambda c: c.kind)
def test_store_round_trip_is_exact(cls, tmp_path):
    art = make_artifact(cls, np.random.default_rng(1))
    store = ArtifactStore(tmp_path)
    assert store.put("k" * 64, art)
    assert store.get("k" * 64, cls).equals(art)


_READ_IN_FRESH_PROCESS = """
import json, sys
from infra.store import ArtifactStore
store = ArtifactStore(sys.argv[1])
out = {}
for kind, key in json.loads(sys.argv[2]).items():
    art = store.get(key)
    out[kind] = {n: len(v) for n, v in dict(art).items() if isinstance(v, list)}
print(json.dumps(out))
"""


def test_a_fresh_process_reads_nested_lists_back(tmp_path):
    """A process that has built no artifact yet reads every nested list back whole. A list typed
    with a class defined further down its module (MaskSequenceArtifact.depth_joints) stayed a
    forward reference there until the first validation, and was read back empty: a rerun from the
    store lost the part finder's joints."""
    store = ArtifactStore(tmp_path)
    keys, expected = {}, {}
    for i, cls in enumerate(ALL):
        art = make_artifact(cls, np.random.default_rng(2))
        keys[cls.kind] = f"{i:064d}"
        assert store.put(keys[cls.kind], art)
        expected[cls.kind] = {n: len(v) for n, v in dict(art).items() if isinstance(v, list)}
    run = subprocess.run([sys.executable, "-c", _READ_IN_FRESH_PROCESS, str(tmp_path), json.dumps(keys)],
                         capture_output=True, text=True, check=True, cwd=Path(__file__).parents[2])
    assert json.loads(run.stdout) == expected
    assert expected["mask_sequence"]["depth_joints"] == 2


def test_frame_arrays_are_chunked_one_frame_per_chunk():
    art = make_artifact(CaptureArtifact, np.random.default_rng(2))
    group = zarr.open_group(MemoryStore(), mode="w")
    art.to_zarr(group)
    assert group["rgb"].chunks == (1, 5, 4, 3)
    assert group["depth"].chunks == (1, 3, 2)


def test_wrong_dtype_and_inconsistent_dims_are_rejected():
    good = make_artifact(CaptureArtifact, np.random.default_rng(3))
    with pytest.raises(ValueError, match="dtype float32"):
        good.model_validate({**dict(good), "depth": good.depth.astype(np.float64)})
    with pytest.raises(ValueError, match="dim 'T'"):
        good.model_validate({**dict(good), "timestamps": np.zeros(99)})


def test_reading_a_different_kind_or_version_is_a_clear_error():
    group = zarr.open_group(MemoryStore(), mode="w")
    StageReport(stage="x").to_zarr(group)
    with pytest.raises(SchemaError, match="expected 'capture'"):
        CaptureArtifact.from_zarr(group)
    group.attrs["artitwin_schema_version"] = 99
    with pytest.raises(SchemaError, match="schema version 99"):
        Artifact.from_zarr(group)


def test_configs_reject_unknown_fields():
    with pytest.raises(ValueError, match="extra"):
        schemas.PipelineConfig.model_validate({"ingest": {"strid": 2}})


def test_presets_size_the_work_for_the_hardware():
    from schemas import PipelineConfig

    assert PipelineConfig.preset("full") == PipelineConfig()
    cpu = PipelineConfig.preset("default")
    assert (cpu.ingest.rgb_max_side, cpu.ingest.keyframes_max) == (640, 100)
    assert (cpu.reconstruct.train_max_side, cpu.articulate.train_max_side) == (384, 256)
    assert cpu.refine_poses.max_features is None and cpu.refine_poses.loop_closure_pairs > 0
    assert cpu.predict_views.max_frames == 16
    gpu = PipelineConfig.preset("default", gpu=True)
    assert gpu.ingest.rgb_max_side is None and gpu.reconstruct.train_max_side is None
    assert gpu.articulate.train_max_side is None
    # The diagnosis's effect fits run on the CPU whatever renders: its prediction is bounded alike.
    assert gpu.predict_views == cpu.predict_views
    assert gpu.reconstruct.max_gaussians == 1_000_000 and gpu.reconstruct.steps == 7000
    with pytest.raises(ValueError, match="known: default, quick, full"):
        PipelineConfig.preset("fast")
