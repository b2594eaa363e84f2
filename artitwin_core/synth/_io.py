"""Writing a synthetic scene to disk in a capture format, with its ground truth beside it.

Layout of ``out_dir``::

    static.r3d, dynamic.r3d        (fmt="r3d"; folders static/, dynamic/ for other formats)
    scene.json                     {"static": "static.r3d", "dynamic": "dynamic.r3d"}
    ground_truth/arrays.npz        masks, true poses, session transform, part motions, joint q
    ground_truth/truth.json        joints, effects, the SceneSpec, frame conventions
"""

from __future__ import annotations

import dataclasses
import json
from pathlib import Path

import numpy as np

from artitwin_core._errors import InputError
from artitwin_core.joints import Joint
from artitwin_core.synth._generate import SyntheticScene
from artitwin_core.synth._spec import SceneSpec
from artitwin_core.synth._types import SceneGroundTruth

GT_VERSION = 1
WRITE_FORMATS = ("r3d", "nerfstudio", "record3d-exr", "stray")


def _jsonable(obj):
    if isinstance(obj, dict):
        return {str(k): _jsonable(v) for k, v in obj.items()}
    if isinstance(obj, list | tuple):
        return [_jsonable(v) for v in obj]
    if isinstance(obj, np.ndarray):
        return obj.tolist()
    if isinstance(obj, np.generic):
        return obj.item()
    return obj


def spec_to_json(spec: SceneSpec) -> dict:
    """A JSON-ready dict of ``spec`` (tuples become lists)."""
    return _jsonable(dataclasses.asdict(spec))


def spec_from_json(data: dict) -> SceneSpec:
    """Inverse of :func:`spec_to_json`."""
    d = dict(data)
    for key in ("size_m", "rgb_size", "depth_size"):
        d[key] = tuple(d[key])
    d["effects"] = tuple((name, dict(params)) for name, params in d.get("effects", ()))
    return SceneSpec(**d)


def write_ground_truth(truth: SceneGroundTruth, spec: SceneSpec, folder: str | Path) -> Path:
    """Write ``truth`` (and the spec that made it) to ``folder``; returns the folder."""
    folder = Path(folder)
    folder.mkdir(parents=True, exist_ok=True)
    arrays = {
        "part_masks": truth.part_masks,
        "hand_masks": truth.hand_masks,
        "static_world_from_camera": truth.static_world_from_camera,
        "dynamic_world_from_camera": truth.dynamic_world_from_camera,
        "canonical_from_dynamic_session": truth.canonical_from_dynamic_session,
    }
    if truth.part_world_from_closed is not None:
        arrays["part_world_from_closed"] = truth.part_world_from_closed
    joints = []
    for k, j in enumerate(truth.joints):
        arrays[f"joint{k}_q"] = j.q
        arrays[f"joint{k}_residual"] = j.residual
        arrays[f"joint{k}_confidence"] = j.confidence
        joints.append({"joint_type": j.joint_type, "axis": j.axis, "pivot": j.pivot,
                       "q_range": j.q_range, "pitch": j.pitch})
    np.savez_compressed(folder / "arrays.npz", **arrays)
    meta = {
        "version": GT_VERSION,
        "canonical_frame": "the static recording's world frame; y up (gravity along -y), metres; "
                           "cameras OpenCV axes; part_masks 0 = none, k + 1 = part k",
        "joints": joints,
        "effects": truth.effects,
        "overlap_fraction": truth.overlap_fraction,
        "spec": spec_to_json(spec),
    }
    (folder / "truth.json").write_text(json.dumps(_jsonable(meta), indent=2))
    return folder


def load_ground_truth(scene_dir: str | Path) -> SceneGroundTruth:
    """Read the ground truth that :func:`write_scene` wrote under ``scene_dir/ground_truth``."""
    folder = Path(scene_dir) / "ground_truth"
    npz_path, json_path = folder / "arrays.npz", folder / "truth.json"
    for p in (npz_path, json_path):
        if not p.is_file():
            raise InputError(f"{p}: missing; a synthetic scene folder written by write_scene has it. "
                             "Regenerate the scene or point at the scene folder itself.")
    try:
        meta = json.loads(json_path.read_text())
        npz = np.load(npz_path)
        arrays = {k: npz[k] for k in npz.files}
    except (OSError, ValueError, json.JSONDecodeError) as exc:
        raise InputError(f"{folder}: cannot read the ground truth ({exc}); regenerate the scene.") from exc
    if meta.get("version") != GT_VERSION:
        raise InputError(f"{json_path}: ground-truth version {meta.get('version')!r}, this reader knows "
                         f"{GT_VERSION}; regenerate the scene with this version of ArtiTwin.")
    joints = [
        Joint(joint_type=j["joint_type"], axis=np.asarray(j["axis"], dtype=np.float64),
              pivot=np.asarray(j["pivot"], dtype=np.float64), q=arrays[f"joint{k}_q"],
              q_range=np.asarray(j["q_range"], dtype=np.float64), residual=arrays[f"joint{k}_residual"],
              confidence=arrays[f"joint{k}_confidence"], pitch=float(j["pitch"]))
        for k, j in enumerate(meta["joints"])
    ]
    return SceneGroundTruth(
        joints=joints,
        part_masks=arrays["part_masks"],
        hand_masks=arrays["hand_masks"],
        static_world_from_camera=arrays["static_world_from_camera"],
        dynamic_world_from_camera=arrays["dynamic_world_from_camera"],
        canonical_from_dynamic_session=arrays["canonical_from_dynamic_session"],
        effects=meta["effects"],
        part_world_from_closed=arrays.get("part_world_from_closed"),
        overlap_fraction=meta.get("overlap_fraction"),
    )


def load_scene_spec(scene_dir: str | Path) -> SceneSpec:
    """The ``SceneSpec`` stored with a scene written by :func:`write_scene`."""
    path = Path(scene_dir) / "ground_truth" / "truth.json"
    if not path.is_file():
        raise InputError(f"{path}: missing; is {scene_dir} a scene folder written by write_scene?")
    return spec_from_json(json.loads(path.read_text())["spec"])


def write_scene(scene: SyntheticScene, out_dir: str | Path, fmt: str = "r3d") -> Path:
    """Write both recordings in capture format ``fmt`` plus ``scene.json`` and the ground truth.

    Args:
        scene: from :func:`generate_scene`.
        out_dir: the scene folder (created).
        fmt: ``"r3d"`` (Record3D archives ``static.r3d``/``dynamic.r3d``), ``"nerfstudio"``,
            ``"record3d-exr"`` or ``"stray"`` (folders ``static/``/``dynamic/``). JPEG (and, for
            Stray, video) compression happens here, in the writers.

    Returns:
        ``out_dir`` as a Path.
    """
    if fmt not in WRITE_FORMATS:
        raise InputError(f"write_scene: fmt={fmt!r}; use one of {WRITE_FORMATS}.")
    # Imported here: the capture writers are heavier (video, EXR) than the generator needs.
    from artitwin_core import capture as cap

    if fmt in ("r3d", "record3d-exr", "stray") and scene.static.distortion is not None:
        raise InputError(
            f"write_scene: {fmt} stores pinhole images only, but this scene records lens distortion "
            "(effect lens_distortion with record=True). Write it with fmt='nerfstudio', or set "
            "record=False to hide the distortion."
        )
    out = Path(out_dir)
    out.mkdir(parents=True, exist_ok=True)
    names = {}
    for role, capture in (("static", scene.static), ("dynamic", scene.dynamic)):
        if fmt == "r3d":
            names[role] = f"{role}.r3d"
            cap.write_r3d(capture, out / names[role])
        else:
            names[role] = role
            writer = {"nerfstudio": cap.write_nerfstudio, "record3d-exr": cap.write_record3d_exr,
                      "stray": cap.write_stray}[fmt]
            writer(capture, out / role)
    (out / "scene.json").write_text(json.dumps(names, indent=2))
    write_ground_truth(scene.truth, scene.spec, out / "ground_truth")
    return out
