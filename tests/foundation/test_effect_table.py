"""One table of effects: schemas._effects.MODELLED_EFFECTS says which effects a stage models; the
core's lists, the CLI help and the docs' tables are checked against it (and the docs' catalogue of
built-in effects against the diagnosis's registry)."""

from __future__ import annotations

import re
from pathlib import Path
from typing import get_args

from schemas import PipelineConfig
from schemas._configs import EFFECT_STAGES, EFFECT_VALUES
from schemas._effects import MODELLED, MODELLED_EFFECTS, PER_RECORDING_EFFECTS, SensorEffect

DOCS = Path(__file__).resolve().parents[2] / "docs"


def _table_names(text: str, heading: str) -> list[str]:
    """The backticked names opening the rows of the first table under ``heading``."""
    lines = text.split(heading, 1)[1].splitlines()
    start = next(i for i, line in enumerate(lines) if line.startswith("|"))
    table = []
    for line in lines[start:]:
        if not line.startswith("|"):
            break
        table.append(line)
    # Each row's first cell names one or more effects, maybe with a scope (`dynamic:vignetting`).
    names = [re.findall(r"`([^`]+)`", row.split("|")[1]) for row in table]
    return list(dict.fromkeys(n.split("=")[0].rpartition(":")[2] for row in names for n in row))


def test_every_modelled_effect_sets_a_field_of_its_stage_config():
    for e in MODELLED_EFFECTS:
        config = getattr(PipelineConfig(), e.stage)
        assert e.field in type(config).model_fields, e
        assert set(e.also) <= set(type(config).model_fields), e
        entry = f"{e.name}=0.01" if e.param else e.name
        if e.name in PER_RECORDING_EFFECTS:  # one row per recording: named with its scope
            entry = f"{e.scopes[0]}:{entry}"
        enabled = PipelineConfig().with_effects([entry])
        assert getattr(getattr(enabled, e.stage), e.field) not in (False, [], 0.0), e  # this row's stage took it
        assert enabled.enabled_effects() == [entry]
    # Each effect's default scope is its first row; a bare name goes there.
    assert EFFECT_STAGES == {name: e.stage for name, e in MODELLED.items()}
    assert PER_RECORDING_EFFECTS == ("exposure_white_balance", "vignetting")
    assert PipelineConfig().with_effects(["vignetting"]).enabled_effects() == ["static:vignetting"]
    assert EFFECT_VALUES == {"time_offset": ("seconds", "rgb_time_offset_s")}


def test_the_core_lists_agree_with_the_table():
    from artitwin_core.diagnostics import registered_effects
    from artitwin_core.reconstruction._sensor import SENSOR_EFFECTS

    assert SENSOR_EFFECTS == get_args(SensorEffect)
    # pose_lag is diagnosed by the recording's self-consistency test (tasks.diagnose), not a plugin.
    assert set(MODELLED) - set(registered_effects()) == {"pose_lag"}


def test_the_docs_tables_list_the_effects():
    from artitwin_core.diagnostics import registered_effects

    modelled = _table_names((DOCS / "add_and_rerun.md").read_text(), "## Which effects can be modelled")
    assert sorted(modelled) == sorted(MODELLED)  # names, whatever their scopes
    built_in = _table_names((DOCS / "effects.md").read_text(), "## Built-in effects")
    assert sorted(built_in) == sorted(registered_effects())


def test_the_cli_offers_every_modelled_effect():
    from artitwin.cli import _EFFECT_HELP

    for e in MODELLED_EFFECTS:
        assert (f"{e.name}={e.param.upper()}" if e.param else e.name) in _EFFECT_HELP
