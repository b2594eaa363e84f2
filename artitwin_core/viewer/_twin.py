"""What the twin viewer shows: Gaussians with part labels, joints, cameras, residuals, collision meshes."""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from artitwin_core._errors import InputError
from artitwin_core.gaussians import LABEL_PART, GaussianParams
from artitwin_core.joints import Joint


@dataclass(frozen=True)
class CameraRig:
    """The capture's cameras, drawn as frustums.

    Attributes:
        world_from_camera: ``[T, 4, 4]`` float64 poses in the canonical frame (OpenCV axes: +z forward, +y down).
        intrinsics: ``[T, 4]`` float64 ``(fx, fy, cx, cy)`` pixels.
        width, height: image size in pixels.
    """

    world_from_camera: np.ndarray
    intrinsics: np.ndarray
    width: int
    height: int

    def __post_init__(self) -> None:
        t = np.asarray(self.world_from_camera).shape[0] if np.ndim(self.world_from_camera) == 3 else -1
        if np.shape(self.world_from_camera) != (t, 4, 4) or np.shape(self.intrinsics) != (t, 4):
            raise InputError(
                f"cameras: world_from_camera {np.shape(self.world_from_camera)} and intrinsics "
                f"{np.shape(self.intrinsics)} must be [T, 4, 4] and [T, 4] with the same T."
            )


@dataclass(frozen=True)
class MeshPiece:
    """One collision mesh, in the canonical frame at the closed state (``q = 0``).

    Attributes:
        name: file stem, e.g. ``door_collision_00``.
        vertices: ``[V, 3]`` float32 metres.
        faces: ``[F, 3]`` int32 vertex indices.
        part: the part it moves with (index into ``TwinData.joints``), or -1 for the fixed base.
    """

    name: str
    vertices: np.ndarray
    faces: np.ndarray
    part: int = -1


@dataclass(frozen=True)
class TwinData:
    """Everything the viewer draws, in the canonical frame (y up), parts at their closed state.

    Attributes:
        gaussians: the Gaussian twin; ``labels`` 0 background, 1 interior, 2 + k part k.
        joints: one joint per part k, with its estimated ``q_range``.
        joint_names: one display name per joint.
        cameras: the capture's cameras, or None.
        residual: ``[N]`` per-Gaussian residual (any unit, e.g. metres), NaN where unknown; or None.
        residual_points: ``[M, 3]`` metres, points carrying ``residual_values [M]``; or None.
        residual_values: ``[M]`` residual per point; or None.
        collision: exported collision meshes (may be empty).
        title: shown in the page title.
        exports: paths of the exported simulator files (URDF, MJCF, USD stage and its payloads), listed
            to the user; the viewer does not read them.
    """

    gaussians: GaussianParams
    joints: tuple[Joint, ...] = ()
    joint_names: tuple[str, ...] = ()
    cameras: CameraRig | None = None
    residual: np.ndarray | None = None
    residual_points: np.ndarray | None = None
    residual_values: np.ndarray | None = None
    collision: tuple[MeshPiece, ...] = field(default_factory=tuple)
    title: str = "ArtiTwin"
    exports: tuple[str, ...] = ()

    def __post_init__(self) -> None:
        n = self.gaussians.num_gaussians
        labels = np.asarray(self.gaussians.labels)
        if labels.shape != (n,):
            raise InputError(f"twin: labels have shape {labels.shape}; expected ({n},), one per Gaussian.")
        top = int(labels.max(initial=0))
        if top - LABEL_PART >= len(self.joints):
            raise InputError(
                f"twin: Gaussians are labelled up to part {top - LABEL_PART} but only {len(self.joints)} joints "
                "were given; pass the joint set the labels were made with."
            )
        if len(self.joint_names) != len(self.joints):
            raise InputError(f"twin: {len(self.joint_names)} joint names for {len(self.joints)} joints.")
        if self.residual is not None and np.shape(self.residual) != (n,):
            raise InputError(f"twin: residual has shape {np.shape(self.residual)}; expected ({n},), one per Gaussian.")
        if (self.residual_points is None) != (self.residual_values is None):
            raise InputError("twin: residual_points and residual_values go together; give both or neither.")
        if self.residual_points is not None:
            m = np.shape(self.residual_values)[0] if np.ndim(self.residual_values) == 1 else -1
            if np.shape(self.residual_points) != (m, 3):
                raise InputError(
                    f"twin: residual_points {np.shape(self.residual_points)} and residual_values "
                    f"{np.shape(self.residual_values)} must be [M, 3] and [M]."
                )
        for piece in self.collision:
            if not -1 <= piece.part < len(self.joints):
                raise InputError(f"twin: collision mesh {piece.name} belongs to part {piece.part}, which has no joint.")

    @property
    def num_parts(self) -> int:
        return len(self.joints)
