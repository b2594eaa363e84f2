"""The simulator export as an artifact (its files, byte for byte) and the export stage's config.

The bundle holds every exported file (URDF, MJCF, OBJ meshes, per-part 3DGS ``.ply``, the
simulator check) as one nested :class:`ExportFile` per file: in zarr that is one ``uint8`` array per
file with its relative path in the group's attributes, so the bundle is cached and content-hashed
like any other artifact, and ``write_files`` lays it out on disk unchanged.
"""

from __future__ import annotations

import re
from pathlib import Path, PurePosixPath
from typing import Literal

import numpy as np
from pydantic import Field, field_validator, model_validator

from schemas._base import Array, Artifact, StageConfig

# One path component: what artitwin_core.export.sanitize_name makes, plus one dot-extension.
_COMPONENT = re.compile(r"^[A-Za-z0-9_][A-Za-z0-9_\-]*(\.[A-Za-z0-9]+)?$")


def check_relative_path(path: str) -> str:
    """``path`` if it is a relative POSIX path of safe components; ValueError naming it otherwise.

    No absolute paths, no ``..``, no backslashes, no empty or hidden components: a bundle's files
    can never be written outside the folder they are exported to.
    """
    if not path or path.startswith("/") or "\\" in path:
        raise ValueError(f"export file path {path!r} must be a non-empty relative POSIX path")
    parts = path.split("/")
    bad = [p for p in parts if not _COMPONENT.match(p)]
    if bad:
        raise ValueError(
            f"export file path {path!r} has unsafe component(s) {bad}: use letters, digits, '_' and '-' "
            "with at most one '.extension' (no '..', no hidden files)"
        )
    return str(PurePosixPath(*parts))


class ExportFile(Artifact):
    """One exported file: its path inside the export folder and its bytes."""

    kind = "export_file"
    schema_version = 1

    path: str = Field(description="Path relative to the export folder, POSIX separators, e.g. 'meshes/base_visual.obj'.")
    data: Array("uint8", "N") = Field(description="The file's contents, N bytes, [N] uint8.")

    @field_validator("path")
    @classmethod
    def _safe_path(cls, value: str) -> str:
        return check_relative_path(value)

    @property
    def content(self) -> bytes:
        return self.data.tobytes()

    @classmethod
    def from_bytes(cls, path: str, content: bytes) -> ExportFile:
        return cls(path=path, data=np.frombuffer(content, np.uint8).copy())


class ExportBundle(Artifact):
    """The exported articulated twin: URDF, MJCF, USD, meshes, per-part splats and the simulator check."""

    kind = "export_bundle"
    schema_version = 1

    files: list[ExportFile] = Field(
        description="Every exported file, paths unique and relative to the export folder (twin.urdf, twin.xml, "
        "twin.usda, payloads/*.usdc, meshes/*.obj, splats/*.ply, sim_check.json)."
    )
    metrics: dict[str, float] = Field(
        default_factory=dict,
        description="Named scalars; unit = suffix: sim_<simulator>_max_error_mm (simulated part pose vs the twin's, "
        "millimetres; simulators include 'usd' and 'newton_usd' for the USD stage), *_count, *_kg, *_s "
        "(usd_write_s, usd_check_s: seconds). A simulator that did not run has no entry.",
    )
    notes: list[str] = Field(default_factory=list, description="Remarks for the user (skipped simulators, screw joints).")

    @model_validator(mode="after")
    def _unique_paths(self) -> ExportBundle:
        seen: set[str] = set()
        for f in self.files:
            key = f.path.lower()  # case-insensitive file systems would merge these
            if key in seen:
                raise ValueError(f"ExportBundle: file path {f.path!r} occurs twice")
            seen.add(key)
        return self

    @property
    def paths(self) -> list[str]:
        return [f.path for f in self.files]

    def file(self, path: str) -> bytes:
        """The bytes of the file at ``path`` (KeyError naming the known paths if absent)."""
        for f in self.files:
            if f.path == path:
                return f.content
        raise KeyError(f"no file {path!r} in the export bundle; it has {self.paths}")

    def write_files(self, out_dir: str | Path) -> list[Path]:
        """Write every file under ``out_dir`` (created); returns the paths written."""
        root = Path(out_dir)
        written = []
        for f in self.files:
            target = root.joinpath(*check_relative_path(f.path).split("/"))
            target.parent.mkdir(parents=True, exist_ok=True)
            target.write_bytes(f.content)
            written.append(target)
        return written


class ExportConfig(StageConfig):
    """Turning the twin into simulator files: fusion, collision shapes, mass, formats and the check."""

    name: str = Field(default="twin", description="Model name and file stem: <name>.urdf, <name>.xml (sanitised).")
    part_voxel_m: float = Field(default=0.01, gt=0, description="TSDF voxel edge for each part's mesh, metres.")
    base_voxel_m: float = Field(default=0.02, gt=0, description="TSDF voxel edge for the base (static scene) mesh, metres.")
    depth_max_m: float = Field(default=4.0, gt=0, description="Depth beyond this is not fused, metres.")
    mask_erode_px: int = Field(
        default=1, ge=0, description="Part masks are eroded by this many depth pixels before fusion (mixed silhouette depth)."
    )
    part_max_faces: int = Field(default=20_000, ge=100, description="Each part's visual mesh is decimated to this many faces.")
    base_max_faces: int = Field(default=30_000, ge=100, description="The base's visual mesh is decimated to this many faces.")
    base_part_margin_m: float = Field(
        default=0.03, gt=0, description="Static depth within this distance of a part mesh is left out of the base, metres."
    )
    base_crop_margin_m: float | None = Field(
        default=1.0,
        gt=0,
        description="The base is cropped to the parts' bounding box (closed and at the range ends) grown by this "
        "much, metres; None keeps the whole static recording (a room makes a large, slow mesh).",
    )
    collision_method: Literal["auto", "coacd", "kmeans"] = Field(
        default="auto", description="Convex decomposition of the parts: CoACD ('auto' = CoACD if installed) or k-means hulls."
    )
    base_collision_method: Literal["auto", "coacd", "kmeans"] = Field(
        default="kmeans", description="Convex decomposition of the base (CoACD on a fused room takes minutes)."
    )
    coacd_threshold: float = Field(
        default=0.1, gt=0, le=1, description="CoACD concavity threshold (smaller = more, tighter pieces)."
    )
    max_collision_pieces: int = Field(default=16, ge=1, description="At most this many convex pieces per part.")
    base_max_collision_pieces: int = Field(default=32, ge=1, description="At most this many convex pieces for the base.")
    density_kg_m3: float = Field(default=500.0, gt=0, description="Uniform density of the parts (500: wood), kg/m^3.")
    effort: float = Field(
        default=50.0, gt=0, description="Joint effort limit (URDF limit, USD drive maxForce), N m (revolute) or N (prismatic)."
    )
    velocity: float = Field(default=1.0, gt=0, description="URDF joint velocity limit, rad/s or m/s.")
    damping: float = Field(
        default=0.5, ge=0, description="Joint damping (MJCF joint, USD passive drive), N m s/rad or N s/m."
    )
    formats: list[Literal["urdf", "mjcf", "usd", "splats"]] = Field(
        default_factory=lambda: ["urdf", "mjcf", "usd", "splats"],
        description="What to write: 'urdf' (twin.urdf), 'mjcf' (twin.xml), 'usd' (twin.usda: OpenUSD stage with a "
        "UsdPhysics articulation and the splats under their links), 'splats' (per-part 3DGS .ply files).",
    )
    usd_payload_min_bytes: int | None = Field(
        default=1 << 18,
        ge=0,
        description="A link whose visual mesh and splats take more than this many bytes keeps them in a binary "
        "payload layer payloads/<link>.usdc beside twin.usda; None keeps everything in the text stage.",
    )
    splats_in_link_frames: bool = Field(
        default=True,
        description="Part .ply means shifted into their URDF link frames (origin at the pivot); False keeps all in the canonical frame.",
    )
    check_simulators: bool = Field(
        default=True,
        description="Load the files in yourdfpy, PyBullet and MuJoCo (the USD stage in pxr, and in Newton if installed) "
        "and drive each joint through its q(t).",
    )
    sim_tolerance_mm: float = Field(
        default=5.0, gt=0, description="A simulated part pose further than this from the twin's is reported as a failure, mm."
    )
    seed: int = Field(default=0, description="Seed of the convex decomposition.")
