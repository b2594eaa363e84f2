"""One pure function per pipeline stage: typed artifacts and a config in, a typed artifact out.

No Prefect here and no hidden I/O: every stage is callable and testable on its own. ``STAGES``
holds the registered stage descriptors by name.
"""

from tasks._convert import to_artifact, to_core
from tasks._stage import STAGES, Stage, stage
from tasks.articulate import articulate_report, articulate_twin
from tasks.calibrate import calibrate_capture_depth, estimate_capture_depth_calibration
from tasks.diagnose import diagnose_dynamic, diagnose_static, diagnose_twin, predict_dynamic, predict_views
from tasks.drift import correct_pose_drift, fit_session_drift, fit_static_drift
from tasks.export import export_twin
from tasks.frame_poses import correct_frame_poses, fit_frame_poses
from tasks.ingest import check_capture, ingest_recording
from tasks.joints import fit_joints, refine_states
from tasks.parts import final_masks, settle_candidate_parts
from tasks.pose_lag import correct_pose_lag, fit_pose_lag
from tasks.reconstruct import reconstruct_canonical, reconstruct_report, refine_capture_poses
from tasks.register import label_parts, part_masks_report, register_dynamic
from tasks.track import track_parts

__all__ = [
    "STAGES",
    "Stage",
    "articulate_report",
    "articulate_twin",
    "calibrate_capture_depth",
    "check_capture",
    "correct_frame_poses",
    "correct_pose_drift",
    "correct_pose_lag",
    "diagnose_dynamic",
    "diagnose_static",
    "diagnose_twin",
    "estimate_capture_depth_calibration",
    "export_twin",
    "final_masks",
    "fit_frame_poses",
    "fit_joints",
    "fit_pose_lag",
    "fit_session_drift",
    "fit_static_drift",
    "ingest_recording",
    "label_parts",
    "part_masks_report",
    "predict_dynamic",
    "predict_views",
    "reconstruct_canonical",
    "reconstruct_report",
    "refine_capture_poses",
    "refine_states",
    "register_dynamic",
    "settle_candidate_parts",
    "track_parts",
    "stage",
    "to_artifact",
    "to_core",
]
