"""ArtiTwin's algorithms: arrays and tensors in, arrays and tensors out.

This package never imports prefect, zarr or pydantic (the import-linter contract in
pyproject.toml enforces it). One sub-package per concern; each re-exports a handful of names
from private ``_module.py`` files.
"""

from artitwin_core._errors import ArtiTwinError, InputError, TransientError
from artitwin_core._progress import ProgressSink, ProgressTask, add_sink, progress, remove_sink

__all__ = ["ArtiTwinError", "InputError", "ProgressSink", "ProgressTask", "TransientError", "add_sink", "progress", "remove_sink"]
