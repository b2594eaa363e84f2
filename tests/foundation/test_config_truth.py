"""One truth per setting: every stage config field acts on a core config field (or a core
function's keyword parameter) with the same default, or says why it acts on none.

The maps are declared beside each stage (``tasks._convert.config_map``); this walks every stage
config the pipeline holds, nested sections included.
"""

from __future__ import annotations

import dataclasses
import inspect

import pytest

import tasks  # noqa: F401 (registers every stage and its config map)
from schemas import PipelineConfig, StageConfig
from tasks._convert import CONFIG_MAPS, config_map, config_map_of, core_value, home_default
from tasks._stage import STAGES


def _stage_configs() -> list[type[StageConfig]]:
    """Every stage config class reachable from PipelineConfig and the registered stages."""
    seen: list[type[StageConfig]] = []
    todo = [info.annotation for info in PipelineConfig.model_fields.values()]
    # The project's stages only: tests register toy stages of their own (tests/flows/_toy.py), and
    # whether they are registered when this module is collected depends on the test order.
    todo += [s.config_type for s in STAGES.values() if s.fn.__module__.split(".")[0] == "tasks"]
    while todo:
        cls = todo.pop()
        if not (isinstance(cls, type) and issubclass(cls, StageConfig)) or cls in seen:
            continue
        seen.append(cls)
        todo += [info.annotation for info in cls.model_fields.values()]
    return sorted(seen, key=lambda c: c.__name__)


CONFIGS = _stage_configs()


def test_every_stage_config_is_found_and_mapped():
    assert len(CONFIGS) >= 20
    assert set(CONFIGS) == set(CONFIG_MAPS), "a stage config without a config_map, or a map of no stage config"


@pytest.mark.parametrize("cls", CONFIGS, ids=lambda c: c.__name__)
def test_every_field_has_a_home_with_the_same_default(cls):
    m = config_map_of(cls)
    mismatched = []
    for home, names in m.homes.items():
        for s, c in names.items():
            core = home_default(home, c)
            if core is inspect.Parameter.empty:
                continue  # the core takes it without a default: the stage config's is the only one
            stage = core_value(cls.model_fields[s].get_default(call_default_factory=True))
            same = stage == core and type(stage) is type(core) or (stage == core and {type(stage), type(core)} <= {int, float})
            if not same and s not in m.differs:
                mismatched.append(f"{cls.__name__}.{s} = {stage!r} but {getattr(home, '__qualname__', home)}.{c} = {core!r}")
            if same and s in m.differs:
                mismatched.append(f"{cls.__name__}.{s} is declared to differ but does not: drop it from differs")
    assert not mismatched, "\n".join(mismatched)


@pytest.mark.parametrize("cls", CONFIGS, ids=lambda c: c.__name__)
def test_stage_only_fields_say_why(cls):
    m = config_map_of(cls)
    assert all(len(why) > 20 for why in (*m.stage_only.values(), *m.differs.values()))


def test_a_field_with_no_home_is_refused():
    class Loose(StageConfig):
        known: int = 1
        orphan: int = 2

    @dataclasses.dataclass(frozen=True)
    class Core:
        known: int = 1

    with pytest.raises(TypeError, match="orphan"):
        config_map(Loose, {Core: "known"})
    with pytest.raises(TypeError, match="missing"):
        config_map(Loose, {Core: {"known": "missing"}}, stage_only={"orphan": "a switch of the stage itself"})
    CONFIG_MAPS.pop(Loose, None)


def test_a_nested_section_converts_to_its_core_dataclass():
    from artitwin_core.change import PartConfig
    from schemas import PartMasksConfig

    cfg = PartMasksConfig.model_validate({"parts": {"grow_frames": 3, "change": {"depth_tol_m": 0.05}}})
    part = core_value(cfg.parts)
    assert isinstance(part, PartConfig)
    assert part.grow_frames == 3 and part.change.depth_tol_m == 0.05
    assert core_value(PartMasksConfig().parts) == PartConfig()


def test_the_schemas_vocabularies_are_the_cores():
    """schemas does not import the core, so it writes its Literal types again: they must agree."""
    from typing import get_args

    from artitwin_core.gaussians import BackendName
    from artitwin_core.joints import JOINT_TYPES, Joint, JointType
    from artitwin_core.parts import FATES, Fate
    from schemas import _vocab
    from schemas._artifacts import JointParams, PartFateArtifact
    from schemas._reconstruct import ReconstructConfig

    assert get_args(_vocab.JointType) == get_args(JointType) == JOINT_TYPES
    assert get_args(_vocab.Fate) == get_args(Fate) == FATES
    assert get_args(_vocab.BackendName) == get_args(BackendName)
    assert JointParams.model_fields["joint_type"].annotation == _vocab.JointType
    assert PartFateArtifact.model_fields["fate"].annotation == _vocab.Fate
    assert Joint.__dataclass_fields__["joint_type"].type == "JointType"
    with pytest.raises(ValueError, match="'revolute'"):
        JointParams.model_validate({"joint_type": "hinge"})
    with pytest.raises(ValueError, match="'cuda'"):
        ReconstructConfig(backend="gpu")


def test_a_pipeline_config_stored_before_the_renames_still_reads():
    """Stored configs are keyed by PipelineConfig's field names, which the class renames
    (RegisterConfig, TrackConfig, FramePosesConfig) left alone; part_masks.parts is new and
    defaults to the part finder's own settings."""
    stored = PipelineConfig().model_dump(mode="json")
    del stored["part_masks"]["parts"]
    stored["track"] = {"max_tracks": 500}
    stored["registration"]["photometric"] = False
    stored["frame_poses"]["enabled"] = False
    cfg = PipelineConfig.model_validate(stored)
    assert cfg.track.max_tracks == 500 and not cfg.registration.photometric and not cfg.frame_poses.enabled
    assert cfg.part_masks == PipelineConfig().part_masks
