"""Benchmark of stage II part masks (issue 5) on the synthetic benchmark scenes, from the pipeline's
own upstream outputs.

Per scene of ``artitwin_core.synth.BENCHMARK_SCENES``, as the pipeline's ``part_masks`` stage
runs it: register the dynamic recording (``register_recordings``), fuse the static recording into
the canonical TSDF (``build_canonical_tsdf``) at the static poses ``refine_poses`` returns (the
``refine_poses`` stage's output; ``--static-poses recorded`` or ``true`` fuses at the capture's
recorded or the true poses instead), then ``segment_parts`` with the estimated registration. Predicted labels are matched one-to-one to true parts by IoU over the recording.
Per (scene, part): the median / 10th percentile / min IoU over frames where the part is visible
(> 50 true pixels), how many such frames, and the medians of the missed fraction (true part
pixels not labelled it: false negatives) and of the spurious fraction (predicted pixels not in
the true part: false positives); per scene: true hand pixels labelled any part. Targets: median
IoU >= 0.85 per part, hand-as-part <= 5 %.

Run: ``python bench/bench_masks.py [--scenes door drawer ...] [--per-frame] [--overlays DIR]``;
prints a table and writes ``bench/results/masks.json``. ``--cache DIR`` keeps each scene's
registration and canonical mesh between runs (for iterating on the mask stage only). Pose
refinement (COLMAP) takes about half a minute per scene on two cores.
"""

from __future__ import annotations

import argparse
import pickle
import sys
import time
from pathlib import Path

import numpy as np
from scipy.optimize import linear_sum_assignment

sys.path.insert(0, str(Path(__file__).resolve().parent))

from _common import print_table, write_results  # noqa: E402

from artitwin_core.change import CanonicalMesh, PartConfig, build_canonical_tsdf, segment_parts  # noqa: E402
from artitwin_core.reconstruction import PoseRefineConfig, refine_poses  # noqa: E402
from artitwin_core.registration import RegistrationConfig, register_recordings  # noqa: E402
from artitwin_core.synth import BENCHMARK_SCENES, generate_scene  # noqa: E402

DEFAULT_SCENES = list(BENCHMARK_SCENES)
GRAVITY = (0.0, -1.0, 0.0)
MIN_PX = 50


def match_labels(pred: np.ndarray, gt: np.ndarray) -> dict[int, int]:
    """True part k + 1 -> predicted label, one-to-one by IoU over all frames (0: unmatched)."""
    k_gt, k_pred = int(gt.max()), int(pred.max())
    out = {k + 1: 0 for k in range(k_gt)}
    if k_gt == 0 or k_pred == 0:
        return out
    iou = np.zeros((k_gt, k_pred))
    for i in range(k_gt):
        g = gt == i + 1
        for j in range(k_pred):
            p = pred == j + 1
            iou[i, j] = np.sum(g & p) / max(np.sum(g | p), 1)
    for r, c in zip(*linear_sum_assignment(-iou), strict=True):
        if iou[r, c] > 0:
            out[int(r) + 1] = int(c) + 1
    return out


def per_frame(pred: np.ndarray, gt: np.ndarray, match: dict[int, int]) -> dict[int, list[dict]]:
    """Per true part, per frame where it is visible: IoU, missed and spurious fractions."""
    out = {}
    for k, lab in match.items():
        rows = []
        for t in range(gt.shape[0]):
            g = gt[t] == k
            if g.sum() <= MIN_PX:
                continue
            p = (pred[t] == lab) if lab else np.zeros_like(g)
            rows.append({
                "frame": t,
                "true_px": int(g.sum()),
                "iou": float(np.sum(g & p) / np.sum(g | p)),
                "missed": float(np.sum(g & ~p) / g.sum()),
                "spurious": float(np.sum(p & ~g) / max(p.sum(), 1)),
            })
        out[k] = rows
    return out


def _static_poses(scene, source: str) -> np.ndarray:
    """``[T, 4, 4]`` static poses the canonical TSDF is fused at."""
    if source == "true":
        return scene.truth.static_world_from_camera
    if source == "recorded":
        return scene.static.world_from_camera
    return refine_poses(scene.static, PoseRefineConfig()).world_from_camera


def _upstream(name: str, cache: Path | None, static_poses: str = "refined"):
    path = cache / f"{name}.{static_poses}.pkl" if cache else None
    if path is not None and path.exists():
        with path.open("rb") as f:
            scene, reg_pose, (v, tri, col), t_up = pickle.load(f)
        return scene, reg_pose, CanonicalMesh(v, tri, col), t_up
    scene = generate_scene(BENCHMARK_SCENES[name])
    t1 = time.perf_counter()
    reg = register_recordings(scene.static, scene.dynamic, gravity=GRAVITY, config=RegistrationConfig())
    mesh = build_canonical_tsdf(scene.static, world_from_camera=_static_poses(scene, static_poses))
    t_up = time.perf_counter() - t1
    if path is not None:
        path.parent.mkdir(parents=True, exist_ok=True)
        with path.open("wb") as f:
            pickle.dump((scene, reg.canonical_from_session, (mesh.vertices, mesh.triangles, mesh.colors), t_up), f)
    return scene, reg.canonical_from_session, mesh, t_up


def _overlays(directory: Path, name: str, scene, pred: np.ndarray, frames: list[int]) -> None:
    import cv2

    directory.mkdir(parents=True, exist_ok=True)
    gt = scene.truth.part_masks
    for t in frames:
        img = scene.dynamic.rgb[t].astype(np.float32) * 0.5
        g, p = gt[t] > 0, pred[t] > 0
        img[g & p] += (0, 110, 0)  # green: right
        img[g & ~p] += (120, 0, 0)  # red: missed
        img[p & ~g] += (0, 0, 120)  # blue: spurious
        img[scene.truth.hand_masks[t] & p] += (110, 110, 0)  # yellow: hand labelled part
        big = cv2.resize(np.clip(img, 0, 255).astype(np.uint8), None, fx=3, fy=3, interpolation=cv2.INTER_NEAREST)
        cv2.imwrite(str(directory / f"{name}_{t:03d}.png"), big[..., ::-1])


def bench_scene(
    name: str, cache: Path | None, show: bool, overlays: Path | None, static_poses: str = "refined"
) -> tuple[list[dict], dict]:
    scene, canonical_from_session, mesh, t_up = _upstream(name, cache, static_poses)
    t0 = time.perf_counter()
    seg = segment_parts(scene.dynamic, canonical_from_session, mesh, gravity=GRAVITY, config=PartConfig())
    t_masks = time.perf_counter() - t0
    gt, pred, hand = scene.truth.part_masks, seg.masks.part, scene.truth.hand_masks
    match = match_labels(pred, gt)
    frames = per_frame(pred, gt, match)
    hand_as_part = float(np.sum(hand & (pred > 0)) / max(np.sum(hand), 1))
    rows = []
    for k, fr in frames.items():
        ious = np.array([r["iou"] for r in fr])
        joint = scene.truth.joints[k - 1].joint_type
        rows.append({
            "scene": name, "part": f"{k}:{joint}", "frames": len(fr),
            "iou_median": float(np.median(ious)) if len(ious) else float("nan"),
            "iou_p10": float(np.quantile(ious, 0.1)) if len(ious) else float("nan"),
            "iou_min": float(ious.min()) if len(ious) else float("nan"),
            "missed_median": float(np.median([r["missed"] for r in fr])) if fr else float("nan"),
            "spurious_median": float(np.median([r["spurious"] for r in fr])) if fr else float("nan"),
            "hand_as_part": hand_as_part, "parts_found": len(seg.models),
            "masks_s": t_masks, "upstream_s": t_up,
        })
        if show:
            print(f"  {name} part {k} ({joint}) label {match[k]}")
            for r in fr:
                print(f"    t={r['frame']:3d} px={r['true_px']:5d} IoU={r['iou']:.3f} missed={r['missed']:.3f} "
                      f"spurious={r['spurious']:.3f}")
    if overlays is not None:
        worst = sorted({r["frame"] for fr in frames.values() for r in sorted(fr, key=lambda r: r["iou"])[:3]})
        _overlays(overlays, name, scene, pred, worst)
    detail = {"per_frame": {str(k): v for k, v in frames.items()},
              "models": [{"type": m.joint_type, "q_ref": float(m.reference_q), "reference_frame": int(m.reference_frame)}
                         for m in seg.models]}
    return rows, detail


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--scenes", nargs="*", default=DEFAULT_SCENES)
    parser.add_argument("--cache", type=Path, default=None, help="keep registration + mesh per scene here")
    parser.add_argument("--per-frame", action="store_true", help="print per-frame IoU")
    parser.add_argument("--overlays", type=Path, default=None, help="write PNGs of the worst frames here")
    parser.add_argument("--static-poses", choices=["refined", "recorded", "true"], default="refined",
                        help="static poses the canonical TSDF is fused at (refined: as the pipeline)")
    args = parser.parse_args()
    rows, details = [], {}
    for name in args.scenes:
        r, d = bench_scene(name, args.cache, args.per_frame, args.overlays, args.static_poses)
        rows += r
        details[name] = d
        for row in r:
            print(f"{name} part {row['part']}: IoU median {row['iou_median']:.3f} over {row['frames']} frames, "
                  f"hand-as-part {row['hand_as_part']:.3f}", flush=True)
    columns = ["scene", "part", "frames", "iou_median", "iou_p10", "iou_min", "missed_median", "spurious_median",
               "hand_as_part", "parts_found", "masks_s"]
    print(f"\nStage II from the pipeline's own registration and canonical TSDF ({args.static_poses} static poses).\n")
    print_table(rows, columns)
    path = write_results("masks", rows, {"targets": {"iou_median": 0.85, "hand_as_part": 0.05},
                                         "static_poses": args.static_poses, "details": details})
    print(f"\nwrote {path}")


if __name__ == "__main__":
    main()
