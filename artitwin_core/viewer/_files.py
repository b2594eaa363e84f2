"""Read a twin from plain files: a 3DGS ``.ply``, a joints JSON, labels, residuals, an export folder."""

from __future__ import annotations

import json
import re
from pathlib import Path

import numpy as np

from artitwin_core._errors import InputError
from artitwin_core.export import sanitize_name
from artitwin_core.gaussians import GaussianParams
from artitwin_core.joints import JOINT_TYPES, Joint
from artitwin_core.viewer._twin import CameraRig, MeshPiece, TwinData

_COLLISION = re.compile(r"^(?P<link>.+)_collision_(?P<i>\d+)$")
_PART_LINK = re.compile(r"^part_(\d+)$")


def read_joints_json(path: str | Path) -> tuple[list[Joint], list[str], CameraRig | None]:
    """Joints (and optional cameras) from JSON.

    Accepts a run's ``summary.json`` or any file holding ``{"joints": [...]}`` or a bare list, each
    joint as the summary writes it: ``name``, ``type``, ``axis [3]``, ``pivot [3]`` metres, ``range
    [2]``, optional ``pitch`` (m/rad) and ``q``. An optional ``"cameras"`` entry holds
    ``world_from_camera [T][4][4]``, ``intrinsics [T][4]`` (fx, fy, cx, cy), ``width``, ``height``.
    """
    path = Path(path)
    try:
        data = json.loads(path.read_text())
    except (OSError, ValueError) as e:
        raise InputError(f"{path}: cannot read joints JSON ({e}).") from None
    entries = data.get("joints", []) if isinstance(data, dict) else data
    if not isinstance(entries, list):
        raise InputError(f"{path}: 'joints' must be a list of joints.")
    joints, names = [], []
    for i, e in enumerate(entries):
        try:
            jtype = str(e["type"])
            axis = np.asarray(e["axis"], np.float64).reshape(3)
            pivot = np.asarray(e["pivot"], np.float64).reshape(3)
            q_range = np.asarray([np.nan if v is None else v for v in e.get("range", [0.0, 0.0])], np.float64).reshape(2)
            q = np.asarray([np.nan if v is None else v for v in e.get("q", [0.0])], np.float64).reshape(-1)
            pitch = float(e.get("pitch", 0.0) or 0.0)
        except (KeyError, TypeError, ValueError) as err:
            raise InputError(f"{path}: joint {i} is malformed ({err!r}); need type, axis [3], pivot [3], range [2].") from None
        if jtype not in JOINT_TYPES:
            raise InputError(f"{path}: joint {i} has type {jtype!r}; expected one of {JOINT_TYPES}.")
        if not np.all(np.isfinite(axis)) or np.linalg.norm(axis) < 1e-9:
            raise InputError(f"{path}: joint {i} has a zero or non-finite axis {axis.tolist()}.")
        nan = np.full(q.shape, np.nan)
        joints.append(Joint(jtype, axis / np.linalg.norm(axis), pivot, q, q_range, nan, nan, pitch))
        names.append(str(e.get("name", f"joint_{i}")))
    cameras = None
    if isinstance(data, dict) and data.get("cameras"):
        c = data["cameras"]
        try:
            cameras = CameraRig(
                np.asarray(c["world_from_camera"], np.float64),
                np.asarray(c["intrinsics"], np.float64),
                int(c["width"]),
                int(c["height"]),
            )
        except (KeyError, TypeError, ValueError) as err:
            raise InputError(f"{path}: 'cameras' is malformed ({err!r}).") from None
    return joints, names, cameras


def read_collision_meshes(export_dir: str | Path, joint_names: list[str], joints: list[Joint]) -> list[MeshPiece]:
    """Collision pieces ``meshes/<link>_collision_NN.obj`` of an export folder, in the canonical frame.

    The base link's pieces are in the canonical frame already; a part's link frame sits at its
    joint's pivot with canonical axes (see ``artitwin_core.export``), so its pieces are shifted
    back by ``+pivot``. Links are matched to joints by sanitised name, else as ``part_<k>`` (the
    export stage's link of joint k); pieces of unknown links are skipped.
    """
    import trimesh

    export_dir = Path(export_dir)
    mesh_dir = export_dir / "meshes" if (export_dir / "meshes").is_dir() else export_dir
    by_link = {sanitize_name(n).lower(): k for k, n in enumerate(joint_names)}
    pieces = []
    for f in sorted(mesh_dir.glob("*_collision_*.obj")):
        m = _COLLISION.match(f.stem)
        if m is None:
            continue
        link = m.group("link").lower()
        part = -1 if link == "base" else by_link.get(link)
        if part is None and (idx := _PART_LINK.match(link)) is not None and int(idx.group(1)) < len(joints):
            part = int(idx.group(1))
        if part is None:
            continue
        try:
            mesh = trimesh.load(f, force="mesh", process=False)
        except Exception as e:  # trimesh raises many types for a bad file
            raise InputError(f"{f}: cannot read collision mesh ({e}).") from None
        vertices = np.asarray(mesh.vertices, np.float64)
        if part >= 0:
            vertices = vertices + np.asarray(joints[part].pivot, np.float64)
        pieces.append(MeshPiece(f.stem, vertices.astype(np.float32), np.asarray(mesh.faces, np.int32), part))
    return pieces


# The simulator files of an export folder: what a user opens elsewhere (Isaac Sim, MuJoCo, ROS).
_MODEL_SUFFIXES = (".urdf", ".xml", ".usda", ".usdc", ".usd")


def model_files(paths) -> tuple[str, ...]:
    """The simulator files among ``paths`` (URDF, MJCF, USD), stages first and payload layers last."""
    keep = [str(p) for p in paths if Path(p).suffix in _MODEL_SUFFIXES]
    return tuple(sorted(keep, key=lambda p: (Path(p).parent.name == "payloads", p)))


def list_export_files(export_dir: str | Path) -> tuple[str, ...]:
    """``model_files`` of an export folder (``twin.urdf``, ``twin.xml``, ``twin.usda``,
    ``payloads/*.usdc``); empty if the folder does not exist."""
    root = Path(export_dir)
    if not root.is_dir():
        return ()
    return model_files(p for pattern in ("*", "payloads/*") for p in root.glob(pattern) if p.is_file())


def read_residual(path: str | Path) -> tuple[np.ndarray | None, np.ndarray | None, np.ndarray | None]:
    """A residual array from ``.npy``: ``[N]`` per Gaussian, or ``[M, 4]`` rows ``(x, y, z, value)``.

    Returns ``(per_gaussian, points, values)`` with the unused entries None.
    """
    path = Path(path)
    try:
        arr = np.load(path, allow_pickle=False)
    except (OSError, ValueError) as e:
        raise InputError(f"{path}: cannot read residual array ({e}).") from None
    if arr.ndim == 1:
        return arr.astype(np.float32), None, None
    if arr.ndim == 2 and arr.shape[1] == 4:
        return None, arr[:, :3].astype(np.float32), arr[:, 3].astype(np.float32)
    raise InputError(f"{path}: residual has shape {arr.shape}; expected [N] (per Gaussian) or [M, 4] (x, y, z, value).")


def read_twin_files(
    ply: str | Path,
    joints_json: str | Path | None = None,
    *,
    labels: str | Path | None = None,
    residual: str | Path | None = None,
    export_dir: str | Path | None = None,
) -> TwinData:
    """A ``TwinData`` from a 3DGS ``.ply`` plus optional joints JSON, labels ``.npy`` ``[N]`` int,
    residual ``.npy`` (see ``read_residual``) and export folder (collision meshes)."""
    from artitwin_core.reconstruction import read_ply  # torch-heavy package: import on use only

    params = read_ply(ply)
    joints, names, cameras = read_joints_json(joints_json) if joints_json is not None else ([], [], None)
    if labels is not None:
        try:
            lab = np.load(labels, allow_pickle=False)
        except (OSError, ValueError) as e:
            raise InputError(f"{labels}: cannot read labels ({e}).") from None
        if lab.shape != (params.num_gaussians,) or not np.issubdtype(lab.dtype, np.integer):
            raise InputError(
                f"{labels}: labels are {lab.dtype} {lab.shape}; expected integers [{params.num_gaussians}], one per Gaussian."
            )
        params = GaussianParams(params.means, params.quats_wxyz, params.log_scales, params.opacity_logits, params.sh,
                                lab.astype(np.int32))
    per_gaussian, points, values = read_residual(residual) if residual is not None else (None, None, None)
    collision = read_collision_meshes(export_dir, names, joints) if export_dir is not None else []
    return TwinData(
        params,
        tuple(joints),
        tuple(names),
        cameras,
        per_gaussian,
        points,
        values,
        tuple(collision),
        title=Path(ply).stem,
        exports=list_export_files(export_dir) if export_dir is not None else (),
    )
