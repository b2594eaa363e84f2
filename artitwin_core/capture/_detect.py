"""Which format a recording is in, reading it whatever the format, and listing its files."""

from __future__ import annotations

import zipfile
from pathlib import Path

from artitwin_core._errors import InputError
from artitwin_core.capture._nerfstudio import nerfstudio_files, read_nerfstudio, transforms_path
from artitwin_core.capture._options import ReadOptions
from artitwin_core.capture._r3d import read_r3d
from artitwin_core.capture._record3d_exr import exr_frame_files, read_record3d_exr
from artitwin_core.capture._stray import read_stray, stray_files
from artitwin_core.capture._types import Capture

FORMATS = ("record3d-r3d", "record3d-exr", "nerfstudio", "stray")
_LOOKED_FOR = (
    "a Record3D .r3d file (a ZIP with a 'metadata' entry); a Record3D EXR+JPG folder (metadata.json, "
    "rgb/, depth/, possibly inside EXR_RGBD/); a nerfstudio folder or transforms.json; a Stray Scanner "
    "folder (rgb.mp4, odometry.csv, camera_matrix.csv, depth/)"
)


def _resolve(path: Path) -> tuple[str, Path]:
    """``(format, root)``: the format and the file or folder its reader takes."""
    if path.is_file():
        if path.name == "transforms.json":
            return "nerfstudio", path
        if zipfile.is_zipfile(path):
            try:
                with zipfile.ZipFile(path) as zf:
                    if "metadata" in zf.namelist():
                        return "record3d-r3d", path
            except (zipfile.BadZipFile, OSError):
                pass
        if path.suffix.lower() == ".r3d":
            # Named like a Record3D file: let the reader say what is wrong with it.
            return "record3d-r3d", path
        raise InputError(f"{path}: the file is not a recording. Looked for {_LOOKED_FOR}.")
    if path.is_dir():
        for root in (path, path / "EXR_RGBD"):
            if (root / "metadata.json").is_file() and ((root / "rgb").is_dir() or (root / "depth").is_dir()):
                return "record3d-exr", root
        if (path / "transforms.json").is_file():
            return "nerfstudio", path / "transforms.json"
        if (path / "rgb.mp4").is_file() and (path / "odometry.csv").is_file():
            return "stray", path
        found = sorted(p.name for p in path.iterdir())[:12]
        raise InputError(f"{path}: no recording found in this folder (it holds {found}). "
                         f"Looked for {_LOOKED_FOR}.")
    raise InputError(f"{path}: no such file or folder. Check the path.")


def detect_format(path: str | Path) -> str:
    """One of ``record3d-r3d``, ``record3d-exr``, ``nerfstudio``, ``stray`` for a recording at
    ``path``; raises :class:`InputError` saying what it looked for when none matches."""
    return _resolve(Path(path))[0]


_READERS = {
    "record3d-r3d": read_r3d,
    "record3d-exr": read_record3d_exr,
    "nerfstudio": read_nerfstudio,
    "stray": read_stray,
}


def read_capture(path: str | Path, options: ReadOptions | None = None) -> Capture:
    """Read a recording in any supported format (see :func:`detect_format`) into a
    :class:`Capture` whose ``source_format`` names the format."""
    fmt, root = _resolve(Path(path))
    return _READERS[fmt](root, options)


def recording_files(path: str | Path) -> list[Path]:
    """The files that make up a recording, sorted, for content hashing (``[N]`` paths).

    Only files a reader uses: an ``.r3d`` is one file; a Record3D export its ``metadata.json``
    and frame files; a nerfstudio dataset ``transforms.json`` and the files it names; a Stray
    folder its video, CSVs, depth and confidence maps (not ``imu.csv``).
    """
    fmt, root = _resolve(Path(path))
    if fmt == "record3d-r3d":
        files = [root]
    elif fmt == "record3d-exr":
        rgb, depth = exr_frame_files(root)
        files = [root / "metadata.json", *rgb.values(), *depth.values()]
    elif fmt == "nerfstudio":
        files = nerfstudio_files(transforms_path(root))
    else:
        files = stray_files(root)
    return sorted({Path(f) for f in files})
