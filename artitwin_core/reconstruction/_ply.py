"""The standard 3DGS ``.ply`` layout (INRIA's ``point_cloud.ply``), written and read exactly.

Binary little-endian float32 vertices with properties ``x y z nx ny nz f_dc_0..2
f_rest_0..(3(K-1)-1) opacity scale_0..2 rot_0..3``: ``f_rest`` channel-major (all red
coefficients, then green, then blue), opacity as a logit, scales as logs, rotation wxyz, normals
zero. This is what the INRIA viewer, SuperSplat, gsplat's exporters and most web viewers read.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np

from artitwin_core._errors import InputError
from artitwin_core.gaussians import LABEL_BACKGROUND, GaussianParams


def _property_names(num_rest: int) -> list[str]:
    names = ["x", "y", "z", "nx", "ny", "nz", "f_dc_0", "f_dc_1", "f_dc_2"]
    names += [f"f_rest_{i}" for i in range(num_rest)]
    names += ["opacity", "scale_0", "scale_1", "scale_2", "rot_0", "rot_1", "rot_2", "rot_3"]
    return names


def write_ply(path: str | Path, params: GaussianParams) -> Path:
    """Write ``params`` as a 3DGS ``.ply`` (labels are not part of the format and are dropped)."""
    n, k = params.num_gaussians, params.sh.shape[1]
    rest = np.asarray(params.sh[:, 1:], np.float32)  # [N, K-1, 3]
    f_rest = rest.transpose(0, 2, 1).reshape(n, 3 * (k - 1))  # channel-major, as INRIA
    cols = [
        np.asarray(params.means, np.float32),
        np.zeros((n, 3), np.float32),
        np.asarray(params.sh[:, 0], np.float32),
        f_rest,
        np.asarray(params.opacity_logits, np.float32)[:, None],
        np.asarray(params.log_scales, np.float32),
        np.asarray(params.quats_wxyz, np.float32),
    ]
    data = np.ascontiguousarray(np.concatenate(cols, axis=1), dtype="<f4")
    names = _property_names(3 * (k - 1))
    header = ["ply", "format binary_little_endian 1.0", f"element vertex {n}"]
    header += [f"property float {name}" for name in names]
    header += ["end_header"]
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    with open(path, "wb") as f:
        f.write(("\n".join(header) + "\n").encode("ascii"))
        f.write(data.tobytes())
    return path


def read_ply(path: str | Path) -> GaussianParams:
    """Read a 3DGS ``.ply`` (binary little-endian, float properties) into ``GaussianParams``.

    Extra float properties are ignored; labels are set to background.
    """
    path = Path(path)
    with open(path, "rb") as f:
        raw = f.read()
    end = raw.find(b"end_header\n")
    if not raw.startswith(b"ply") or end < 0:
        raise InputError(f"{path}: not a PLY file (no 'ply' magic or 'end_header').")
    header = raw[:end].decode("ascii", errors="replace").splitlines()
    if "format binary_little_endian 1.0" not in header:
        raise InputError(f"{path}: only binary little-endian 3DGS PLY files are supported.")
    n, names = None, []
    for line in header:
        parts = line.split()
        if parts[:2] == ["element", "vertex"]:
            n = int(parts[2])
        elif parts[:1] == ["property"]:
            if parts[1] not in ("float", "float32"):
                raise InputError(f"{path}: property {parts[-1]} is {parts[1]}; 3DGS PLY files hold float32 only.")
            names.append(parts[2])
    if n is None:
        raise InputError(f"{path}: no 'element vertex' line in the header.")
    body = raw[end + len(b"end_header\n") :]
    if len(body) < n * len(names) * 4:
        raise InputError(f"{path}: truncated ({len(body)} bytes of vertex data, need {n * len(names) * 4}).")
    data = np.frombuffer(body[: n * len(names) * 4], dtype="<f4").reshape(n, len(names))
    col = {name: i for i, name in enumerate(names)}
    need = ["x", "y", "z", "f_dc_0", "f_dc_1", "f_dc_2", "opacity", "scale_0", "scale_1", "scale_2"]
    need += ["rot_0", "rot_1", "rot_2", "rot_3"]
    missing = [m for m in need if m not in col]
    if missing:
        raise InputError(f"{path}: missing 3DGS properties {missing}.")
    num_rest = sum(1 for name in names if name.startswith("f_rest_"))
    if num_rest % 3 or int(round(np.sqrt(num_rest // 3 + 1))) ** 2 != num_rest // 3 + 1:
        raise InputError(f"{path}: {num_rest} f_rest properties is not 3((d+1)^2 - 1) for an SH degree d.")
    k = num_rest // 3 + 1

    def take(prefix: str, count: int) -> np.ndarray:
        return np.stack([data[:, col[f"{prefix}{i}"]] for i in range(count)], axis=1).astype(np.float32)

    sh = np.zeros((n, k, 3), np.float32)
    sh[:, 0] = take("f_dc_", 3)
    if k > 1:
        sh[:, 1:] = take("f_rest_", num_rest).reshape(n, 3, k - 1).transpose(0, 2, 1)
    return GaussianParams(
        means=np.stack([data[:, col[a]] for a in "xyz"], axis=1).astype(np.float32),
        quats_wxyz=take("rot_", 4),
        log_scales=take("scale_", 3),
        opacity_logits=data[:, col["opacity"]].astype(np.float32).copy(),
        sh=sh,
        labels=np.full(n, LABEL_BACKGROUND, np.int32),
    )
