"""A scene: two recordings of one room, ``static`` (before) and ``dynamic`` (a part moves)."""

from __future__ import annotations

import json
from dataclasses import dataclass
from pathlib import Path

from artitwin_core._errors import InputError

_LAYOUT = ("Lay the scene out as <scene>/static.r3d and <scene>/dynamic.r3d (or folders named "
           "static/ and dynamic/, or static.<ext>/dynamic.<ext>), or write <scene>/scene.json as "
           '{"static": "relative/path", "dynamic": "relative/path"}.')


@dataclass(frozen=True)
class SceneRecordings:
    """Paths of a scene's two recordings (each a file or folder any reader accepts)."""

    static: Path
    dynamic: Path


def _from_manifest(scene: Path, manifest: Path) -> SceneRecordings:
    try:
        data = json.loads(manifest.read_text())
    except (OSError, UnicodeDecodeError, json.JSONDecodeError) as exc:
        raise InputError(f"{manifest}: cannot read the scene manifest ({exc}). {_LAYOUT}") from exc
    if not isinstance(data, dict):
        raise InputError(f"{manifest}: expected a JSON object. {_LAYOUT}")
    for role in ("static", "dynamic"):
        if not isinstance(data.get(role), str) or not data[role]:
            raise InputError(f"{manifest}: field {role!r} is missing or not a path. {_LAYOUT}")
    out = {}
    for role in ("static", "dynamic"):
        rel = data[role]
        p = (scene / rel).resolve()
        if not p.exists():
            raise InputError(f"{manifest}: the {role} recording {rel!r} does not exist (resolved to {p}). "
                             "Fix the path in scene.json.")
        out[role] = p
    if out["static"] == out["dynamic"]:
        raise InputError(f"{manifest}: 'static' and 'dynamic' name the same recording {out['static']}. "
                         "A scene needs two different recordings.")
    return SceneRecordings(static=out["static"], dynamic=out["dynamic"])


def find_scene_recordings(scene_dir: str | Path) -> SceneRecordings:
    """The ``static`` and ``dynamic`` recordings of the scene folder ``scene_dir``.

    ``scene.json`` wins when present; otherwise entries named ``static``/``dynamic`` or
    ``static.<ext>``/``dynamic.<ext>`` (files or folders). Raises :class:`InputError` when the
    folder is missing, a role has no recording or more than one candidate.
    """
    scene = Path(scene_dir)
    if not scene.is_dir():
        raise InputError(f"{scene}: the scene folder does not exist. {_LAYOUT}")
    manifest = scene / "scene.json"
    if manifest.is_file():
        return _from_manifest(scene, manifest)
    entries = sorted(p for p in scene.iterdir() if not p.name.startswith("."))
    out = {}
    for role in ("static", "dynamic"):
        hits = [p for p in entries if p.name == role or p.name.startswith(role + ".")]
        if not hits:
            raise InputError(f"{scene}: no {role} recording found (the folder holds "
                             f"{[p.name for p in entries][:12]}). {_LAYOUT}")
        if len(hits) > 1:
            raise InputError(f"{scene}: several candidates for the {role} recording: "
                             f"{[p.name for p in hits]}. Keep one, or name it in scene.json.")
        out[role] = hits[0]
    return SceneRecordings(static=out["static"], dynamic=out["dynamic"])
