"""What the ``artitwin`` commands share: the error console, the ``--store`` option, failing with a
message, and loading a pipeline config file."""

from __future__ import annotations

import json
from pathlib import Path
from typing import Annotated

import typer
from pydantic import ValidationError
from rich.console import Console

from schemas import PipelineConfig

console = Console(stderr=True)

StoreOpt = Annotated[
    str | None,
    typer.Option("--store", help="Store root: a directory or an fsspec URL (default: $ARTITWIN_STORE or ./.artitwin/store)."),
]


def _fail(message: str, code: int = 2) -> None:
    console.print(f"[bold red]error:[/] {message}")
    raise typer.Exit(code)


def _load_config(path: Path | None, preset: str = "default"):
    if path is None:
        try:
            from flows import hardware_preset

            return hardware_preset(preset)
        except ValueError as e:
            _fail(str(e))
    if not path.is_file():
        _fail(f"config file {path} does not exist")
    text = path.read_text()
    try:
        if path.suffix in (".yaml", ".yml"):
            import yaml

            data = yaml.safe_load(text) or {}
        else:
            data = json.loads(text)
        return PipelineConfig.model_validate(data)
    except (ValueError, ValidationError) as e:
        _fail(f"config file {path} is invalid:\n{e}")
