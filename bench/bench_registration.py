"""Benchmark of registration, change detection and part-mask propagation on the synthetic scenes.

Per scene of ``artitwin_core.synth.BENCHMARK_SCENES``: register the dynamic recording onto the
static one (``register_recordings``), fuse the static recording into a TSDF mesh as the canonical
model at the poses ``refine_poses`` returns (``build_canonical_tsdf``, as the pipeline does; the
canonical renderer here is this TSDF ray-caster, not the Gaussian splatting twin), then label
every dynamic frame (``segment_parts``) using the *estimated* registration, end to end. Reports
rotation / translation error of the registration (degrees / metres; the translation of
``canonical_from_session`` is its error at the dynamic session's origin, which lies up to a few
metres from the furniture), the largest displacement of the cabinet's eight corners
(``furniture_err_m``: where the error matters) beside the registration's own standard error there
(``furniture_se_m``, from its block-jackknife covariance), its residual (metres), the median part-mask IoU
over frames where a part is visible (> 50 pixels; predicted labels matched to true parts by best
IoU), the fraction of true
hand pixels labelled part, and seconds per stage (noisy: the machine is shared).

A second table (issue 24) registers recordings that overlap only in part, share one AR session,
or do not overlap at all, registration alone: the static sweep cut to its first or last 30 % of
frames (``partial``), the static sweep's two halves (``same-session``: the truth is the
identity), renders of the room's front wall and front-left corner, which the static sweep never
saw, and another scene's dynamic recording scaled 1.3x, a bigger room (``no-overlap``: a refusal
is the right answer). ``colour_agreement`` is the texture test's correlation at the refined placement
(for a refusal before the fine stages, the coarse best's; see ``RegistrationConfig.min_colour_agreement``).
``true_overlap`` is the share of the dynamic points within 2 cm of a static one at the truth.

Run: ``python bench/bench_registration.py [--scenes door drawer ...] [--overlap-scenes door ...]
[--only-overlap]``; prints the tables and writes ``bench/results/registration.json``.
"""

from __future__ import annotations

import argparse
import sys
import time
from dataclasses import replace
from pathlib import Path

import numpy as np
from scipy.optimize import linear_sum_assignment

sys.path.insert(0, str(Path(__file__).resolve().parent))

from _common import print_table, write_results  # noqa: E402
from scipy.spatial import cKDTree  # noqa: E402

from artitwin_core.capture import Capture  # noqa: E402
from artitwin_core.change import build_canonical_tsdf, segment_parts  # noqa: E402
from artitwin_core.reconstruction import PoseRefineConfig, refine_poses  # noqa: E402
from artitwin_core.registration import RegistrationError, fused_cloud, register_recordings  # noqa: E402
from artitwin_core.synth import BENCHMARK_SCENES, generate_scene, render_state  # noqa: E402
from artitwin_core.synth._motion import look_at  # noqa: E402


def pose_errors(estimate: np.ndarray, truth: np.ndarray) -> tuple[float, float]:
    d = np.linalg.inv(truth) @ estimate
    angle = np.degrees(np.arccos(np.clip((np.trace(d[:3, :3]) - 1.0) / 2.0, -1.0, 1.0)))
    return float(angle), float(np.linalg.norm(estimate[:3, 3] - truth[:3, 3]))


def furniture_error(estimate: np.ndarray, truth: np.ndarray, size_m) -> float:
    """Largest displacement (metres) of the cabinet's corners under ``estimate`` vs ``truth``.

    The synthetic cabinet stands on the floor (y = 0), front face at z = 0, centred on x = 0."""
    w, h, d = size_m
    corners = np.array([[x, y, z, 1.0] for x in (-w / 2, w / 2) for y in (0.0, h) for z in (-d, 0.0)])
    # The same canonical point, mapped through session coordinates by each transform.
    diff = estimate @ np.linalg.inv(truth) @ corners.T - corners.T
    return float(np.linalg.norm(diff[:3], axis=0).max())


def furniture_se(covariance, size_m) -> float:
    """The registration's own standard error (metres, RMS over axes) at the cabinet's corners,
    the worst corner, from ``RegistrationResult.covariance``; NaN where it was not estimated."""
    if covariance is None:
        return float("nan")
    w, h, d = size_m
    worst = 0.0
    for corner in [np.array([x, y, z]) for x in (-w / 2, w / 2) for y in (0.0, h) for z in (-d, 0.0)]:
        skew = np.array([[0, -corner[2], corner[1]], [corner[2], 0, -corner[0]], [-corner[1], corner[0], 0]])
        jac = np.hstack([-skew, np.eye(3)])
        worst = max(worst, float(np.sqrt(np.trace(jac @ covariance @ jac.T))))
    return worst


def mask_metrics(pred: np.ndarray, gt: np.ndarray, hand: np.ndarray, min_px: int = 50) -> dict:
    """Median IoU over (frame, true part) pairs with the part visible, after matching labels."""
    k_gt, k_pred = int(gt.max()), int(pred.max())
    if k_gt == 0:
        return {"mask_iou_median": float("nan"), "mask_iou_min": float("nan"), "parts_found": k_pred}
    inter = np.zeros((k_gt, max(k_pred, 1)))
    union = np.ones((k_gt, max(k_pred, 1)))
    for i in range(k_gt):
        for j in range(k_pred):
            inter[i, j] = np.sum((gt == i + 1) & (pred == j + 1))
            union[i, j] = np.sum((gt == i + 1) | (pred == j + 1))
    rows, cols = linear_sum_assignment(-(inter / union))
    match = {int(r) + 1: int(c) + 1 for r, c in zip(rows, cols, strict=True) if k_pred}
    ious = []
    for t in range(gt.shape[0]):
        for k in range(1, k_gt + 1):
            g = gt[t] == k
            if g.sum() < min_px:
                continue
            p = pred[t] == match[k] if k in match else np.zeros_like(g)
            ious.append(np.sum(g & p) / np.sum(g | p))
    hand_as_part = float(np.sum(hand & (pred > 0)) / max(np.sum(hand), 1))
    return {
        "mask_iou_median": float(np.median(ious)) if ious else float("nan"),
        "mask_iou_min": float(np.min(ious)) if ious else float("nan"),
        "hand_as_part": hand_as_part,
        "parts_found": k_pred,
        "parts_true": k_gt,
    }


def run_scene(name: str) -> dict:
    t0 = time.perf_counter()
    scene = generate_scene(BENCHMARK_SCENES[name])
    t1 = time.perf_counter()
    reg = register_recordings(scene.static, scene.dynamic)
    t2 = time.perf_counter()
    # Fused at refine_poses' output, as the pipeline's part_masks stage fuses it.
    mesh = build_canonical_tsdf(scene.static, world_from_camera=refine_poses(scene.static, PoseRefineConfig()).world_from_camera)
    t3 = time.perf_counter()
    seg = segment_parts(scene.dynamic, reg.canonical_from_session, mesh)
    t4 = time.perf_counter()
    rot, trans = pose_errors(reg.canonical_from_session, scene.truth.canonical_from_dynamic_session)
    row = {
        "scene": name,
        "rot_err_deg": rot,
        "trans_err_m": trans,
        "furniture_err_m": furniture_error(
            reg.canonical_from_session, scene.truth.canonical_from_dynamic_session, BENCHMARK_SCENES[name].size_m
        ),
        "furniture_se_m": furniture_se(reg.covariance, BENCHMARK_SCENES[name].size_m),
        "residual_m": reg.residual_m,
        "inliers": reg.inlier_fraction,
        **mask_metrics(seg.masks.part, scene.truth.part_masks, scene.truth.hand_masks),
        "register_s": t2 - t1,
        "tsdf_s": t3 - t2,
        "masks_s": t4 - t3,
        "generate_s": t1 - t0,
    }
    row["joints"] = [
        {"type": m.joint_type, "q_ref": float(m.reference_q), "reference_frame": int(m.reference_frame)}
        for m in seg.models
    ]
    return row


def true_overlap(static: Capture, dynamic: Capture, canonical_from_session: np.ndarray) -> float:
    """Share of the dynamic points (2 cm voxels) within 2 cm of a static point at the truth."""
    s = np.asarray(fused_cloud(static, range(static.num_frames), voxel_m=0.02).points)
    d = np.asarray(fused_cloud(dynamic, range(dynamic.num_frames), voxel_m=0.02).points)
    d = d @ canonical_from_session[:3, :3].T + canonical_from_session[:3, 3]
    return float(np.mean(cKDTree(s).query(d)[0] < 0.02))


def rendered(scene, eyes: np.ndarray, targets: np.ndarray, n: int = 12) -> Capture:
    """A clean recording of ``scene`` (parts closed) from cameras moving from ``eyes[0]`` to
    ``eyes[1]``, looking from ``targets[0]`` to ``targets[1]``, in the dynamic session's frame."""
    st = scene.static
    (w, h), (dw, dh) = st.rgb_size, st.depth_size
    t = np.linspace(0.0, 1.0, n)[:, None]
    poses = look_at(eyes[0] + t * (eyes[1] - eyes[0]), targets[0] + t * (targets[1] - targets[0]), np.zeros(n))
    q = [0.0] * len(scene.truth.joints)
    return Capture(
        rgb=np.stack([render_state(scene, p, st.rgb_intrinsics[0], w, h, q)[0] for p in poses]),
        depth=np.stack([render_state(scene, p, st.depth_intrinsics[0], dw, dh, q)[1] for p in poses]),
        confidence=None, rgb_intrinsics=np.tile(st.rgb_intrinsics[0], (n, 1)),
        depth_intrinsics=np.tile(st.depth_intrinsics[0], (n, 1)),
        world_from_camera=np.linalg.inv(scene.truth.canonical_from_dynamic_session) @ poses,
        timestamps=np.arange(n) / 15.0, frame_ids=np.arange(n) * 2, source_format="synthetic",
    )


UNSEEN_VIEWS = {  # canonical frame: eyes (start, end), targets (start, end)
    "front wall": (np.array([[-0.6, 1.3, 1.4], [0.6, 1.3, 1.4]]), np.array([[-0.6, 1.0, 3.2], [0.6, 1.0, 3.2]])),
    "front-left corner": (np.array([[-1.0, 1.3, 1.6], [-0.7, 1.3, 1.6]]), np.array([[-2.3, 0.8, 2.4], [-2.3, 0.8, 3.2]])),
}


def overlap_cases(name: str):
    """``(case, static, dynamic, truth or None)`` for one benchmark scene: truth None = must refuse."""
    scene = generate_scene(BENCHMARK_SCENES[name])
    st, truth = scene.static, scene.truth.canonical_from_dynamic_session
    k = max(2, int(round(0.3 * st.num_frames)))
    yield f"{name} partial: static first {k}", st.select_frames(slice(0, k)), scene.dynamic, truth
    yield f"{name} partial: static last {k}", st.select_frames(slice(st.num_frames - k, None)), scene.dynamic, truth
    half = st.num_frames // 2
    yield f"{name} same-session halves", st.select_frames(slice(0, half)), st.select_frames(slice(half, None)), np.eye(4)
    for view, (eyes, targets) in UNSEEN_VIEWS.items():
        yield f"{name} no-overlap: {view}", st, rendered(scene, eyes, targets), None
    # Another room. The generator's rooms all share one box with the furniture at one place, so
    # another scene at the same scale is the same room geometrically (it registers); scaled
    # 1.3x (depth and poses) it is a bigger room with bigger furniture.
    other = generate_scene(replace(BENCHMARK_SCENES[name], furniture="drawer" if "door" in name else "door",
                                   size_m=(1.2, 1.1, 0.5), seed=BENCHMARK_SCENES[name].seed + 1000)).dynamic
    poses = other.world_from_camera.copy()
    poses[:, :3, 3] *= 1.3
    bigger = replace(other, depth=(other.depth * 1.3).astype(np.float32), world_from_camera=poses)
    yield f"{name} no-overlap: another room (1.3x)", st, bigger, None


def run_overlap_case(case: str, static: Capture, dynamic: Capture, truth, size_m) -> dict:
    reference = truth if truth is not None else np.eye(4)
    row = {"case": case, "true_overlap": true_overlap(static, dynamic, reference) if truth is not None else float("nan")}
    t0 = time.perf_counter()
    try:
        reg = register_recordings(static, dynamic)
    except RegistrationError as err:
        best = err.hypotheses[0]
        row.update(refused=True, failed="; ".join(f.split(" (")[0][:60] for f in err.failed), support=best.support,
                   est_overlap=best.overlap, inlier_ratio=best.inlier_ratio, colour_agreement=best.colour_agreement,
                   colour_contrast=best.colour_contrast, register_s=time.perf_counter() - t0)
        return row
    final, verdict = reg.diagnostics["final"], reg.diagnostics["verdict"]
    row.update(refused=False, chosen=final["name"], support=final["support"], est_overlap=final["overlap"],
               inlier_ratio=final["inlier_ratio"], rival_ratio=verdict["rival_ratio"], tilt_deg=reg.tilt_deg,
               colour_agreement=final["colour_agreement"], colour_contrast=final["colour_contrast"],
               register_s=time.perf_counter() - t0)
    if truth is not None:
        rot, trans = pose_errors(reg.canonical_from_session, truth)
        row.update(rot_err_deg=rot, furniture_err_m=furniture_error(reg.canonical_from_session, truth, size_m),
                   furniture_se_m=furniture_se(reg.covariance, size_m))
    return row


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--scenes", nargs="*", default=list(BENCHMARK_SCENES))
    parser.add_argument("--overlap-scenes", nargs="*", default=["door", "drawer"])
    parser.add_argument("--only-overlap", action="store_true", help="skip the first table")
    args = parser.parse_args()
    rows = []
    for name in [] if args.only_overlap else args.scenes:
        try:
            row = run_scene(name)
        except RegistrationError as err:  # a refusal is a result: record it, go on
            print(f"{name}: registration refused: {'; '.join(err.failed)}", flush=True)
            rows.append({"scene": name, "refused": True})
            continue
        rows.append(row)
        print(f"{name}: {row['rot_err_deg']:.3f} deg, {row['trans_err_m'] * 100:.2f} cm, "
              f"IoU {row['mask_iou_median']:.3f}, hand-as-part {row.get('hand_as_part', float('nan')):.3f}",
              flush=True)
    columns = ["scene", "rot_err_deg", "trans_err_m", "furniture_err_m", "furniture_se_m", "residual_m", "inliers", "mask_iou_median",
               "mask_iou_min", "hand_as_part", "parts_found", "parts_true", "register_s", "tsdf_s", "masks_s"]
    if rows:
        print("\nCanonical model for change detection: TSDF mesh of the static recording, ray-cast with open3d "
              "(not the Gaussian splatting twin). Masks use the estimated registration.\n")
        print_table(rows, columns)
    overlap_rows = []
    for name in args.overlap_scenes:
        for case, static, dynamic, truth in overlap_cases(name):
            row = run_overlap_case(case, static, dynamic, truth, BENCHMARK_SCENES[name].size_m)
            overlap_rows.append(row)
            print(f"{case}: " + ("refused" if row["refused"] else f"{row.get('rot_err_deg', float('nan')):.3f} deg, "
                                 f"{row.get('furniture_err_m', float('nan')) * 1000:.1f} mm"), flush=True)
    if overlap_rows:
        print("\nPartial overlap, one session, no overlap (registration alone; no-overlap rows must be refused):\n")
        print_table(overlap_rows, ["case", "true_overlap", "refused", "rot_err_deg", "furniture_err_m", "furniture_se_m",
                                   "tilt_deg", "support", "est_overlap", "inlier_ratio", "rival_ratio", "colour_agreement",
                                   "colour_contrast", "register_s", "failed"])
    targets = {"rot_err_deg": 0.5, "trans_err_m": 0.01, "furniture_err_m": 0.01, "mask_iou_median": 0.85, "hand_as_part": 0.05}
    path = write_results(
        "registration", rows,
        {"canonical_renderer": "open3d TSDF mesh ray-cast (build_canonical_tsdf)", "targets": targets,
         "overlap_rows": overlap_rows},
    )
    print(f"\nwrote {path}")


if __name__ == "__main__":
    main()
