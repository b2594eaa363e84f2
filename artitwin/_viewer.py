"""``artitwin view``: the Gaussian twin in the browser, one slider per joint (viser on 127.0.0.1).

Each part's Gaussians live under their own scene node whose pose is ``world_from_part(q)``; a
slider step sends that pose (a few dozen bytes) and the browser re-sorts and redraws, so moving a
part costs the same for 1k or 1M Gaussians. The page is viser's bundled client: nothing is
fetched from the network.
"""

from __future__ import annotations

import json
from dataclasses import dataclass, field, replace
from pathlib import Path

import numpy as np

from artitwin_core._errors import InputError
from artitwin_core.gaussians import LABEL_BACKGROUND, LABEL_INTERIOR, LABEL_PART, GaussianParams
from artitwin_core.viewer import (
    CameraRig,
    TwinData,
    heat_colors,
    list_export_files,
    matrix_to_quat_wxyz,
    model_files,
    part_poses,
    read_collision_meshes,
    slider_range,
    splat_arrays,
)

_JOINT_COLORS = {"revolute": (230, 60, 40), "prismatic": (40, 120, 230), "screw": (160, 60, 200), "fixed": (120, 120, 120)}
MAX_FRUSTUMS = 60  # more clutters the view and the websocket without adding information


@dataclass
class TwinViewer:
    """A running viewer: the viser server and the handles a caller (or a test) may drive."""

    server: object
    twin: TwinData
    sliders: list = field(default_factory=list)
    part_frames: list = field(default_factory=list)
    splats: dict = field(default_factory=dict)
    toggles: dict = field(default_factory=dict)

    @property
    def url(self) -> str:
        return f"http://{self.server.get_host()}:{self.server.get_port()}"

    @property
    def q(self) -> np.ndarray:
        """``[K]`` current joint states from the sliders (radians or metres)."""
        return np.array([float(s.value) for s in self.sliders])

    def set_q(self, q) -> None:
        """Move every part to states ``q [K]``: one pose per part node, sent as one batch."""
        poses = part_poses(self.twin.joints, q)
        with self.server.atomic():
            for frame, pose in zip(self.part_frames, poses, strict=True):
                frame.wxyz = matrix_to_quat_wxyz(pose[:3, :3])
                frame.position = pose[:3, 3]

    def close(self) -> None:
        self.server.stop()


def _extent(means: np.ndarray) -> tuple[np.ndarray, float]:
    """Centre and size (metres) of the bulk of the Gaussians (2nd-98th percentile box)."""
    if means.shape[0] == 0:
        return np.zeros(3), 1.0
    lo, hi = np.percentile(means, 2, axis=0), np.percentile(means, 98, axis=0)
    return (lo + hi) / 2, float(max(np.linalg.norm(hi - lo), 0.1))


def build_viewer(twin: TwinData, host: str = "127.0.0.1", port: int = 8080) -> TwinViewer:
    """Start a viser server showing ``twin``; returns at once (the server runs in its own threads)."""
    import viser

    server = viser.ViserServer(host=host, port=port, label=twin.title, verbose=False)
    server.scene.set_up_direction("+y")
    viewer = TwinViewer(server, twin)
    params = twin.gaussians
    centers, covs, rgbs, opacities = splat_arrays(params)
    labels = np.asarray(params.labels)
    heat = heat_colors(twin.residual) if twin.residual is not None else None
    center, size = _extent(centers)

    def add_splats(name: str, sel: np.ndarray) -> None:
        if sel.any():
            viewer.splats[name] = (
                server.scene.add_gaussian_splats(name, centers[sel], covs[sel], rgbs[sel], opacities[sel]),
                rgbs[sel],
                heat[sel] if heat is not None else None,
            )

    add_splats("/twin/static", labels < LABEL_PART)
    for k in range(twin.num_parts):
        viewer.part_frames.append(server.scene.add_frame(f"/twin/part_{k}", show_axes=False))
        add_splats(f"/twin/part_{k}/splats", labels == LABEL_PART + k)

    # Joint axes: a line through the pivot along the axis, drawn in the fixed (parent) frame.
    axes = []
    for k, j in enumerate(twin.joints):
        part = centers[labels == LABEL_PART + k]
        half = 0.6 * (_extent(part)[1] if part.shape[0] else size * 0.3)
        axis = np.asarray(j.axis, np.float64) / np.linalg.norm(j.axis)
        seg = np.stack([j.pivot - half * axis, j.pivot + half * axis])[None].astype(np.float32)
        color = _JOINT_COLORS.get(j.joint_type, (0, 0, 0))
        axes.append(server.scene.add_line_segments(f"/axes/{k}", seg, color, thickness=3.0, thickness_units="screen"))
        axes.append(server.scene.add_icosphere(f"/axes/{k}_pivot", radius=0.012 * size, color=color,
                                               position=tuple(np.asarray(j.pivot, float))))

    frustums = _add_cameras(server, twin.cameras, size) if twin.cameras is not None else []
    collision = _add_collision(server, twin)
    points = None
    if twin.residual_points is not None:
        points = server.scene.add_point_cloud(
            "/residual_points", twin.residual_points, heat_colors(twin.residual_values), point_size=0.01 * size,
            visible=False,
        )

    if twin.cameras is not None:
        server.initial_camera.position = tuple(np.asarray(twin.cameras.world_from_camera[:, :3, 3].mean(0), float))
    else:
        server.initial_camera.position = tuple(center + np.array([0.0, 0.25, 1.0]) * size)
    server.initial_camera.look_at = tuple(center)

    with server.gui.add_folder("Joints"):
        for j, name in zip(twin.joints, twin.joint_names, strict=True):
            lo, hi = slider_range(j)
            unit = "m" if j.joint_type == "prismatic" else "rad"
            slider = server.gui.add_slider(f"{name} ({unit})", min=lo, max=hi, step=(hi - lo) / 200,
                                           initial_value=float(np.clip(0.0, lo, hi)))
            slider.on_update(lambda _e: viewer.set_q(viewer.q))
            viewer.sliders.append(slider)
        if twin.joints:
            reset = server.gui.add_button("Close all")

            @reset.on_click
            def _(_e) -> None:
                for s in viewer.sliders:
                    s.value = float(np.clip(0.0, s.min, s.max))
                viewer.set_q(viewer.q)

    with server.gui.add_folder("Show"):
        viewer.toggles["axes"] = _toggle(server, "Joint axes", axes, True)
        viewer.toggles["cameras"] = _toggle(server, "Capture cameras", frustums, True)
        viewer.toggles["collision"] = _toggle(server, "Collision meshes", collision, False)
        residual = server.gui.add_checkbox("Residual heat map", False,
                                           disabled=heat is None and points is None,
                                           hint=None if heat is not None or points is not None else "no residuals loaded")

        @residual.on_update
        def _(_e) -> None:
            on = bool(residual.value)
            with server.atomic():
                for handle, colors, heat_rgb in viewer.splats.values():
                    if heat_rgb is not None:
                        handle.rgbs = heat_rgb if on else colors
                if points is not None:
                    points.visible = on

        viewer.toggles["residual"] = residual
    if twin.exports:
        with server.gui.add_folder("Exports"):
            lines = [f"- `{short_export_path(p)}`" for p in twin.exports]
            if any(p.endswith(".usda") for p in twin.exports):
                lines.append("\nIsaac Sim: *File > Open* the `.usda` (see docs/usd.md).")
            server.gui.add_markdown("\n".join(lines))
    return viewer


def short_export_path(path: str) -> str:
    """``twin.usda`` or ``payloads/base.usdc``: an exported file as it sits in its export folder."""
    p = Path(path)
    return f"{p.parent.name}/{p.name}" if p.parent.name == "payloads" else p.name


def _toggle(server, label: str, handles: list, initial: bool):
    box = server.gui.add_checkbox(label, initial, disabled=not handles, hint=None if handles else "nothing to show")
    for h in handles:
        h.visible = initial

    @box.on_update
    def _(_e) -> None:
        with server.atomic():
            for h in handles:
                h.visible = bool(box.value)

    return box


def _add_cameras(server, cams: CameraRig, size: float) -> list:
    step = max(1, int(np.ceil(cams.world_from_camera.shape[0] / MAX_FRUSTUMS)))
    out = []
    for i in range(0, cams.world_from_camera.shape[0], step):
        pose, (_fx, fy, _cx, _cy) = cams.world_from_camera[i], cams.intrinsics[i]
        out.append(server.scene.add_camera_frustum(
            f"/cameras/{i}", fov=float(2 * np.arctan2(cams.height / 2, fy)), aspect=cams.width / cams.height,
            scale=0.03 * size, thickness=1.5, thickness_units="screen", color=(40, 40, 40),
            wxyz=matrix_to_quat_wxyz(pose[:3, :3]), position=pose[:3, 3],
        ))
    return out


def _add_collision(server, twin: TwinData) -> list:
    out = []
    rng = np.random.default_rng(0)  # a stable colour per piece, so neighbouring hulls are told apart
    for piece in twin.collision:
        parent = f"/twin/part_{piece.part}/collision" if piece.part >= 0 else "/collision"
        color = tuple(int(c) for c in rng.integers(80, 230, 3))
        out.append(server.scene.add_mesh_simple(f"{parent}/{piece.name}", piece.vertices, piece.faces,
                                                color=color, opacity=0.6, visible=False))
    return out


# --- loading a twin -------------------------------------------------------------------------------
def load_twin(
    path: str | Path,
    *,
    joints: str | Path | None = None,
    labels: str | Path | None = None,
    residual: str | Path | None = None,
    export_dir: str | Path | None = None,
) -> TwinData:
    """A twin from a run folder (its ``summary.json`` and the store it names), a scene folder that
    was run into ``out/``, or a 3DGS ``.ply`` (with optional joints JSON, labels and residuals)."""
    from artitwin_core.viewer import read_residual, read_twin_files

    path = Path(path)
    if path.suffix == ".ply":
        if not path.is_file():
            raise InputError(f"{path}: no such .ply file.")
        return read_twin_files(path, joints, labels=labels, residual=residual, export_dir=export_dir)
    summary = _find_summary(path)
    twin = _twin_from_summary(summary, export_dir)
    if residual is not None:
        per_gaussian, points, values = read_residual(residual)
        twin = replace(twin, residual=per_gaussian, residual_points=points, residual_values=values)
    return twin


def _find_summary(path: Path) -> Path:
    if path.is_file() and path.name == "summary.json":
        return path
    if (path / "summary.json").is_file():
        return path / "summary.json"
    if path.is_dir():  # a scene folder: look for the run that used it
        scene = str(path.resolve())
        for cand in [Path("out") / path.name / "summary.json", Path("out") / "summary.json", *Path("out").glob("*/summary.json")]:
            try:
                if cand.is_file() and json.loads(cand.read_text()).get("scene") == scene:
                    return cand
            except ValueError:
                continue
    raise InputError(
        f"{path}: no summary.json here and no run of this scene under ./out; give a run folder "
        "(artitwin run SCENE --out DIR), its summary.json, or a 3DGS .ply with --joints."
    )


def _twin_from_summary(summary_path: Path, export_dir: str | Path | None) -> TwinData:
    from artitwin_core.joints import Joint
    from infra.store import ArtifactStore
    from schemas import CameraPoses, CaptureArtifact, GaussianCheckpoint, JointSet
    from tasks._convert import to_core

    summary = json.loads(summary_path.read_text())
    stages = summary.get("stages", {})
    store = ArtifactStore(summary["store"])

    def last(kind: str, label: str | None = None):
        runs = [s for s in stages.values() if s.get("kind") == kind and (label is None or s.get("label") == label)]
        return runs[-1]["key"] if runs else None

    key = last(GaussianCheckpoint.kind)
    if key is None:
        raise InputError(f"{summary_path}: the run has no Gaussian twin (no reconstruct stage output); run it first.")
    params = to_core(GaussianParams, store.get(key, GaussianCheckpoint))
    joints, names = [], []
    if (jkey := last(JointSet.kind)) is not None:
        for jp in store.get(jkey, JointSet).joints:
            joints.append(to_core(Joint, jp))
            names.append(jp.name)
    top = int(np.max(params.labels, initial=0)) - LABEL_PART
    if top >= len(joints):  # labels from a different joint set: show the twin rigid rather than fail
        params = GaussianParams(params.means, params.quats_wxyz, params.log_scales, params.opacity_logits, params.sh,
                                np.zeros_like(params.labels))
    cameras, points, values = None, None, None
    pkey, ckey = last(CameraPoses.kind, "static"), last(CaptureArtifact.kind, "static")
    if pkey is not None and ckey is not None:
        cap = store.get(ckey, CaptureArtifact)
        poses = store.get(pkey, CameraPoses)
        h, w = cap.rgb.shape[1:3]
        cameras = CameraRig(np.asarray(poses.world_from_camera), np.asarray(cap.rgb_intrinsics), int(w), int(h))
        if (vkey := last("view_prediction", "static")) is not None:
            points, values = _depth_residual(store, vkey, cap, poses)
    if export_dir is None:
        found = sorted(summary_path.parent.glob("*/meshes")) + sorted(summary_path.parent.glob("*/*/meshes"))
        export_dir = found[0].parent if found else None
    collision = read_collision_meshes(export_dir, names, joints) if export_dir is not None else []
    # summary.json lists what the run exported; an explicit export folder is listed as it is.
    exports = (list_export_files(export_dir) if export_dir is not None else ()) or model_files(
        summary.get("exports", {}).values())
    per_gaussian = None
    if points is not None and len(points):
        # The residual accumulated onto the model: which Gaussians (and so which part) are wrong.
        from artitwin_core.viewer import residual_on_gaussians

        per_gaussian = residual_on_gaussians(params.means, points, values)
    return TwinData(params, tuple(joints), tuple(names), cameras, residual=per_gaussian, residual_points=points,
                    residual_values=values, collision=tuple(collision),
                    title=Path(summary.get("scene", summary_path.parent)).name, exports=exports)


def _depth_residual(store, key: str, cap, poses) -> tuple[np.ndarray | None, np.ndarray | None]:
    """The diagnostics' predicted depth of the static recording against its measured depth, as points."""
    from artitwin_core.viewer import depth_residual_points
    from schemas._diagnose import ViewPrediction

    pred = store.get(key, ViewPrediction)
    index = {int(f): i for i, f in enumerate(np.asarray(cap.frame_ids))}
    rows = [index.get(int(f), -1) for f in np.asarray(pred.frame_ids)]
    if min(rows, default=-1) < 0 or pred.depth.shape[1:] != cap.depth.shape[1:]:
        return None, None  # a prediction of another recording or size: nothing to compare with
    rows = np.asarray(rows)
    return depth_residual_points(np.asarray(cap.depth)[rows], np.asarray(pred.depth),
                                 np.asarray(cap.depth_intrinsics)[rows], np.asarray(poses.world_from_camera)[rows])


# --- the command ------------------------------------------------------------------------------------
def view(
    path: str | Path,
    *,
    port: int = 8080,
    host: str = "127.0.0.1",
    joints: str | Path | None = None,
    labels: str | Path | None = None,
    residual: str | Path | None = None,
    export_dir: str | Path | None = None,
    block: bool = True,
    echo=print,
) -> TwinViewer:
    """``artitwin view``: load the twin at ``path`` and serve it until Ctrl-C.

    Args:
        path: a run folder (``artitwin run --out DIR``), its ``summary.json``, a scene folder run
            into ``./out``, or a 3DGS ``.ply`` (with ``joints``, ``labels``, ``residual`` files).
        port: the first port tried on ``host``; viser moves to the next free one if it is taken.
        export_dir: the export folder whose collision meshes to show (default: found in the run folder).
        block: serve until Ctrl-C, then stop; False returns the running viewer at once (tests).
        echo: where the URL and what was loaded are reported.

    Raises:
        InputError: ``path`` (or a side file) is missing or malformed; the message says which and why.
    """
    import time

    twin = load_twin(path, joints=joints, labels=labels, residual=residual, export_dir=export_dir)
    viewer = build_viewer(twin, host=host, port=port)
    echo(
        f"{twin.title}: {twin.gaussians.num_gaussians} Gaussians, {twin.num_parts} joint(s), "
        f"{0 if twin.cameras is None else twin.cameras.world_from_camera.shape[0]} cameras, "
        f"{len(twin.collision)} collision meshes"
    )
    if twin.residual is not None and np.isfinite(twin.residual).any():
        from artitwin_core.viewer import residual_by_label

        names = {LABEL_BACKGROUND: "background", LABEL_INTERIOR: "interior"}
        names.update({LABEL_PART + k: n for k, n in enumerate(twin.joint_names)})
        by = residual_by_label(twin.residual, twin.gaussians.labels, names)
        echo("residual per part (mean over its observed Gaussians; a run's depth residual is in metres): "
             + ", ".join(f"{n} {v:.3g}" for n, v in by.items() if np.isfinite(v)))
    if twin.exports:
        usd = [p for p in twin.exports if p.endswith(".usda")]
        folder = Path(twin.exports[0]).parent  # model_files puts the stages (not payloads) first
        echo(f"exports in {folder}: " + ", ".join(short_export_path(p) for p in twin.exports)
             + (f"; open {usd[0]} in Isaac Sim (File > Open)" if usd else ""))
    echo(f"viewer at {viewer.url} (Ctrl-C stops it)")
    if not block:
        return viewer
    try:
        while True:
            time.sleep(3600)
    except KeyboardInterrupt:
        pass
    finally:
        viewer.close()
    return viewer
