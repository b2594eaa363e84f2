"""ArtiTwin's algorithms: arrays and tensors in, arrays and tensors out.

This package never imports prefect, zarr or pydantic (the import-linter contract in
pyproject.toml enforces it). One sub-package per concern; each re-exports a handful of names
from private ``_module.py`` files.
"""

import os

# OpenMP threads that wait by spinning (libgomp's default) stall whenever the cores are shared: the
# pipeline runs two stages at once on two cores, and Open3D's TSDF integration (the part finder's
# canonical mesh) took 22 s instead of 0.3 s for the same 20 frames, with the same mesh. Set here,
# before any module loads an OpenMP runtime; a value the user set wins (docs/performance.md).
os.environ.setdefault("OMP_WAIT_POLICY", "PASSIVE")

from artitwin_core._errors import ArtiTwinError, InputError, TransientError
from artitwin_core._progress import ProgressSink, ProgressTask, add_sink, progress, remove_sink

__all__ = ["ArtiTwinError", "InputError", "ProgressSink", "ProgressTask", "TransientError", "add_sink", "progress", "remove_sink"]
