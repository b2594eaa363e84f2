"""`artitwin compare` judges the frames a stage held out of training by their place in the
recording, not by their place in the diagnosis's curve: with ``PredictViewsConfig.max_frames``
the diagnosis predicts some frames only, and the curve's i-th entry is not the recording's i-th
frame (issue 28)."""

from __future__ import annotations

import json

from artitwin_core.reconstruction import split_frames
from flows._runs import run_record
from infra.store import ArtifactStore
from schemas import DiagnosisReport, PredictViewsConfig
from tasks.diagnose import prediction_frames

STATIC, DYNAMIC = "static recording", "dynamic recording"


def _run_folder(tmp_path, reports: dict[str, DiagnosisReport], config: dict):
    store = ArtifactStore(str(tmp_path / "store"))
    stages = {}
    for i, (stage, report) in enumerate(reports.items()):
        key = f"{i}" * 64
        store.put(key, report)
        stages[stage] = {"status": "computed", "key": key}
    out = tmp_path / "run"
    out.mkdir()
    (out / "summary.json").write_text(json.dumps({"stages": stages, "store": str(tmp_path / "store"), "config": config}))
    return out


def test_heldout_frames_are_the_recordings_not_the_curves(tmp_path):
    n_static, n_dynamic = 60, 45
    cfg = PredictViewsConfig(max_frames=15, run_frames=5)
    s_pos, d_pos = prediction_frames(n_static, cfg), prediction_frames(n_dynamic, cfg)
    assert len(s_pos) == 15 and s_pos != list(range(15))  # a subset: the case that went wrong
    # A curve whose value says which recording frame it is, so the test can read the frames back.
    static = DiagnosisReport(findings=[], per_frame={f"{STATIC}/rgb_rms_before": [float(p) for p in s_pos]},
                             frames={STATIC: s_pos}, recording_frames={STATIC: n_static})
    dynamic = DiagnosisReport(findings=[], per_frame={f"{DYNAMIC}/rgb_rms_before": [float(p) for p in d_pos]},
                              frames={DYNAMIC: d_pos}, recording_frames={DYNAMIC: n_dynamic})
    run = _run_folder(tmp_path, {"diagnose": static, "diagnose_dynamic": dynamic},
                      {"reconstruct": {"holdout_every": 8}, "articulate": {"holdout_every": 6}})
    rec = run_record(run)
    for scope, n, every in ((STATIC, n_static, 8), (DYNAMIC, n_dynamic, 6)):
        name = f"diagnose/{scope}/rgb_rms"
        frames = [int(rec.per_frame[name][i]) for i in rec.heldout[name]]
        truth = [p for p in split_frames(n, every)[1] if p in set(s_pos if scope == STATIC else d_pos)]
        assert frames == truth and frames, (scope, frames, truth)
    # Without positions (every frame predicted) the curve's entries are the recording's frames.
    whole = DiagnosisReport(findings=[], per_frame={f"{STATIC}/rgb_rms_before": [0.0] * 20})
    rec = run_record(_run_folder(tmp_path / "w", {"diagnose": whole}, {"reconstruct": {"holdout_every": 4}}))
    assert rec.heldout[f"diagnose/{STATIC}/rgb_rms"] == [0, 4, 8, 12, 16]
