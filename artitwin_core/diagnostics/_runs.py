"""Compare two runs of one scene: did the error fall, where, and on frames the twin never saw?

A run is reduced to a ``RunRecord``: its flat metrics (``"stage/metric"``), its per-frame error
curves (``"stage/curve"``) and which frames of each curve were held out of training. The
comparison lists every metric whose better direction is known (PSNR and SSIM up; errors,
residual energies, RMS and MAE down) with its change, and for every curve the mean over
training frames, over held-out frames, and over run A's worst quarter of frames (where the
error was concentrated) against the same frames in run B.
"""

from __future__ import annotations

import html
import re
from dataclasses import dataclass, field

import numpy as np

from artitwin_core._errors import InputError
from artitwin_core.diagnostics._report import svg_plot

_HIGHER = re.compile(r"(psnr|ssim|inlier_frac|explained)")
_LOWER = re.compile(r"(mae|rms|energy|error|residual|nll|_deg$|_m$)")
_NOT_QUALITY = re.compile(r"(_count$|seconds|floor|pose_correction|sensor_|_frac$|gaussians|_after$|_se$)")


def better_direction(name: str) -> int:
    """+1 when a larger value of metric ``name`` is better, -1 when smaller is, 0 when unknown."""
    leaf = name.rsplit("/", 1)[-1]
    if _NOT_QUALITY.search(leaf) and not _HIGHER.search(leaf):
        return 0
    if _HIGHER.search(leaf):
        return 1
    if _LOWER.search(leaf):
        return -1
    return 0


@dataclass(frozen=True)
class RunRecord:
    """What a comparison needs of one run.

    Attributes:
        name: a label (the run's output folder).
        effects: the physical effects the run's twin models (its config).
        metrics: ``{"stage/metric": value}``.
        per_frame: ``{"stage/curve": [value per frame]}`` (NaN where not measured).
        heldout: ``{"stage/curve": frame indices held out of training}`` (missing = none known).
    """

    name: str
    effects: list[str] = field(default_factory=list)
    metrics: dict[str, float] = field(default_factory=dict)
    per_frame: dict[str, list[float]] = field(default_factory=dict)
    heldout: dict[str, list[int]] = field(default_factory=dict)


@dataclass(frozen=True)
class MetricChange:
    name: str
    a: float
    b: float
    direction: int  # +1 higher is better, -1 lower is better

    @property
    def relative(self) -> float:
        return (self.b - self.a) / abs(self.a) if self.a not in (0.0,) and np.isfinite(self.a) else float("nan")

    @property
    def improved(self) -> bool:
        return bool(np.isfinite(self.a) and np.isfinite(self.b) and self.direction * (self.b - self.a) > 0)


@dataclass(frozen=True)
class CurveChange:
    """One per-frame error curve in both runs (lower is better), split by where it matters.

    ``*_a`` / ``*_b`` are NaN-ignoring means over: all frames, training frames, held-out frames,
    and ``worst_frames`` (run A's worst quarter, at least one frame)."""

    name: str
    all_a: float
    all_b: float
    train_a: float
    train_b: float
    heldout_a: float
    heldout_b: float
    worst_frames: list[int]
    worst_a: float
    worst_b: float
    rest_a: float
    rest_b: float


@dataclass(frozen=True)
class RunComparison:
    """``lead``: one line per residual the effects B adds target (did the loop work), then one per
    other curve that rose beyond its noise (a regression of the modelling); ``conclusion``: the rest."""

    a: RunRecord
    b: RunRecord
    metrics: list[MetricChange]
    curves: list[CurveChange]
    conclusion: list[str]
    lead: list[str] = field(default_factory=list)
    regressions: list[str] = field(default_factory=list)


# A change in a curve is beyond noise when its mean per-frame change exceeds both this many
# standard errors of the per-frame changes and this share of its level in run A (a retrained
# twin differs from run to run by a few per cent on every frame alike, which the per-frame
# scatter does not see).
NOISE_SE = 2.0
NOISE_REL = 0.05


def curve_shift(a: RunRecord, b: RunRecord, name: str) -> tuple[float, float, int, bool] | None:
    """``(mean A, mean B, frames, beyond noise)`` of curve ``name`` over its held-out frames (all
    frames when none is known held out); None when either run lacks it."""
    if name not in a.per_frame or name not in b.per_frame:
        return None
    ca, cb = np.asarray(a.per_frame[name], float), np.asarray(b.per_frame[name], float)
    if ca.shape != cb.shape:
        return None
    held = [f for f in a.heldout.get(name, []) if f < ca.size] or list(range(ca.size))
    idx = np.asarray(held, int)
    ok = idx[np.isfinite(ca[idx]) & np.isfinite(cb[idx])]
    if ok.size == 0:
        return None
    d = cb[ok] - ca[ok]
    se = float(d.std(ddof=1) / np.sqrt(ok.size)) if ok.size > 1 else float("inf")
    ma, mb = float(ca[ok].mean()), float(cb[ok].mean())
    beyond = abs(mb - ma) > max(NOISE_SE * se, NOISE_REL * abs(ma))
    return ma, mb, int(ok.size), bool(beyond)


def metric_shift(a: RunRecord, b: RunRecord, name: str) -> tuple[float, float, bool] | None:
    """``(A, B, beyond noise)`` of the scalar metric ``name`` (a quantity measured once per run,
    e.g. the static recording's self-consistency depth error); beyond noise when the two differ by
    more than ``NOISE_SE`` of their combined standard errors (the metrics ``NAME_se``, when the
    runs record them) and ``NOISE_REL`` of A. None when either run lacks it."""
    if name not in a.metrics or name not in b.metrics:
        return None
    va, vb = float(a.metrics[name]), float(b.metrics[name])
    if not (np.isfinite(va) and np.isfinite(vb)):
        return None
    sa, sb = (np.nan_to_num(float(r.metrics.get(name + "_se", 0.0))) for r in (a, b))
    se = float(np.hypot(sa, sb))
    return va, vb, bool(abs(vb - va) > max(NOISE_SE * se, NOISE_REL * abs(va)))


def target_shift(a: RunRecord, b: RunRecord, name: str) -> tuple[float, float, int, bool] | None:
    """``(A, B, frames, beyond noise)`` of a comparison target: a curve over its held-out frames
    (``curve_shift``), or a metric measured once per run (``metric_shift``; 0 frames)."""
    shift = curve_shift(a, b, name)
    if shift is None and (scalar := metric_shift(a, b, name)) is not None:
        return scalar[0], scalar[1], 0, scalar[2]
    return shift


def _verdict(ma: float, mb: float, beyond: bool) -> str:
    return ("the loop worked" if mb < ma else "it rose: the modelling made it worse") if beyond else "no change beyond noise"


def _lead(a: RunRecord, b: RunRecord, targets, others) -> tuple[list[str], list[str]]:
    lead, regressions = [], []
    for label, name, effect in targets:
        shift = target_shift(a, b, name)
        if shift is None:
            lead.append(f"{label}: not measured in both runs ({name}); the effect {effect} cannot be judged.")
            continue
        ma, mb, n, beyond = shift
        values = f"{ma:.3g} -> {mb:.3g}, {_pct(ma, mb)}"
        text = f"{label}, held-out: {values} over {n} frames" if n else f"{label}: {values}"
        lead.append(f"{text} ({effect}: {_verdict(ma, mb, beyond)}).")
    targeted = {name for _, name, _ in targets}
    for label, name in others:
        if name in targeted:
            continue
        shift = curve_shift(a, b, name)
        if shift is not None and shift[3] and shift[1] > shift[0]:
            ma, mb, n, _ = shift
            regressions.append(f"regression of the modelling: {label}, held-out: {ma:.3g} -> {mb:.3g}, {_pct(ma, mb)} "
                               f"over {n} frames (beyond its noise).")
    return lead, regressions


def _mean(x: np.ndarray, idx) -> float:
    v = x[np.asarray(list(idx), int)] if len(idx) else np.zeros(0)
    v = v[np.isfinite(v)]
    return float(v.mean()) if v.size else float("nan")


def _pct(a: float, b: float) -> str:
    if not (np.isfinite(a) and np.isfinite(b)) or a == 0:
        return "n/a"
    return f"{100 * (b - a) / abs(a):+.0f}%"


def compare_runs(a: RunRecord, b: RunRecord, targets=(), others=()) -> RunComparison:
    """Compare run ``b`` against run ``a`` (``a`` is "before").

    ``targets``: ``(label, curve, effect)`` for each residual the effects ``b`` adds are meant to
    cut (``("dynamic recording, photometric", "diagnose/dynamic recording/rgb_rms",
    "dynamic:exposure_white_balance")``): the comparison leads with them, on held-out frames.
    ``others``: ``(label, curve)`` of every other scope's curves: one that rises beyond its noise
    (``curve_shift``) is reported as a regression of the modelling."""
    metrics = []
    for name in sorted(set(a.metrics) & set(b.metrics)):
        d = better_direction(name)
        va, vb = float(a.metrics[name]), float(b.metrics[name])
        if d and (np.isfinite(va) or np.isfinite(vb)):
            metrics.append(MetricChange(name, va, vb, d))
    curves = []
    for name in sorted(set(a.per_frame) & set(b.per_frame)):
        ca, cb = np.asarray(a.per_frame[name], float), np.asarray(b.per_frame[name], float)
        if ca.shape != cb.shape:
            raise InputError(
                f"compare: curve {name!r} has {ca.size} frames in {a.name} and {cb.size} in {b.name}; "
                "compare two runs of the same scene and capture settings."
            )
        if better_direction(name) != -1 or not np.isfinite(ca).any():
            continue
        frames = np.arange(ca.size)
        held = sorted(set(a.heldout.get(name, [])) & set(range(ca.size)))
        train = [f for f in frames if f not in set(held)]
        finite = frames[np.isfinite(ca)]
        k = max(1, len(finite) // 4)
        worst = sorted(int(f) for f in finite[np.argsort(-ca[finite])[:k]])
        rest = [f for f in finite if f not in set(worst)]
        curves.append(CurveChange(
            name, _mean(ca, frames), _mean(cb, frames), _mean(ca, train), _mean(cb, train),
            _mean(ca, held), _mean(cb, held), worst, _mean(ca, worst), _mean(cb, worst),
            _mean(ca, rest), _mean(cb, rest),
        ))  # fmt: skip
    lead, regressions = _lead(a, b, list(targets), list(others))
    return RunComparison(a, b, metrics, curves, _conclusion(a, b, metrics, curves), lead, regressions)


def _conclusion(a: RunRecord, b: RunRecord, metrics: list[MetricChange], curves: list[CurveChange]) -> list[str]:
    lines = []
    added = sorted(set(b.effects) - set(a.effects))
    removed = sorted(set(a.effects) - set(b.effects))
    if added or removed:
        lines.append(
            f"{b.name} models {', '.join(added) or 'no new effect'}"
            + (f" and drops {', '.join(removed)}" if removed else "") + f" compared with {a.name}."
        )
    better = [m for m in metrics if m.improved]
    worse = [m for m in metrics if np.isfinite(m.a) and np.isfinite(m.b) and m.direction * (m.b - m.a) < 0]
    lines.append(f"{len(better)} of {len(metrics)} metrics improved, {len(worse)} got worse.")
    key = sorted((m for m in metrics if np.isfinite(m.relative)), key=lambda m: -abs(m.relative))[:3]
    for m in key:
        lines.append(f"{m.name}: {m.a:.4g} -> {m.b:.4g} ({_pct(m.a, m.b)}, {'better' if m.improved else 'worse'}).")
    for c in curves:
        held = (f"; on held-out frames {c.heldout_a:.3g} -> {c.heldout_b:.3g} ({_pct(c.heldout_a, c.heldout_b)})"
                if np.isfinite(c.heldout_a) else "")
        lines.append(
            f"{c.name}: on training frames {c.train_a:.3g} -> {c.train_b:.3g} ({_pct(c.train_a, c.train_b)}){held}; "
            f"on {a.name}'s worst frames {c.worst_frames[:6]}{'...' if len(c.worst_frames) > 6 else ''} "
            f"{c.worst_a:.3g} -> {c.worst_b:.3g} ({_pct(c.worst_a, c.worst_b)}), elsewhere "
            f"{c.rest_a:.3g} -> {c.rest_b:.3g} ({_pct(c.rest_a, c.rest_b)})."
        )
    return lines


def comparison_html(cmp: RunComparison, title: str = "ArtiTwin run comparison") -> str:
    """A self-contained HTML page: the conclusion, the metric table and the curves overlaid."""
    a, b = cmp.a, cmp.b
    body = [f"<h1>{html.escape(title)}</h1>",
            f"<p>A = <b>{html.escape(a.name)}</b> (effects: {html.escape(', '.join(a.effects) or 'none')}); "
            f"B = <b>{html.escape(b.name)}</b> (effects: {html.escape(', '.join(b.effects) or 'none')}).</p><ul>"]
    body += [f"<li><b>{html.escape(line)}</b></li>" for line in cmp.lead + cmp.regressions]
    body += [f"<li>{html.escape(line)}</li>" for line in cmp.conclusion]
    body.append("</ul><h2>Metrics</h2><table border=1 cellpadding=3 style='border-collapse:collapse'>"
                "<tr><th>metric</th><th>A</th><th>B</th><th>change</th><th>better is</th><th></th></tr>")
    for m in sorted(cmp.metrics, key=lambda m: m.name):
        mark = "better" if m.improved else ("worse" if np.isfinite(m.a) and np.isfinite(m.b) and m.a != m.b else "")
        colour = {"better": "#2ca02c", "worse": "#d62728"}.get(mark, "#000")
        body.append(f"<tr><td>{html.escape(m.name)}</td><td>{m.a:.4g}</td><td>{m.b:.4g}</td><td>{_pct(m.a, m.b)}</td>"
                    f"<td>{'higher' if m.direction > 0 else 'lower'}</td><td style='color:{colour}'>{mark}</td></tr>")
    body.append("</table><h2>Per-frame errors</h2><table border=1 cellpadding=3 style='border-collapse:collapse'>"
                "<tr><th>curve</th><th>training A</th><th>training B</th><th>held-out A</th><th>held-out B</th>"
                "<th>A's worst frames: A</th><th>B</th><th>other frames: A</th><th>B</th></tr>")
    for c in cmp.curves:
        body.append(f"<tr><td>{html.escape(c.name)}</td>" + "".join(
            f"<td>{v:.4g}</td>" for v in (c.train_a, c.train_b, c.heldout_a, c.heldout_b, c.worst_a, c.worst_b,
                                         c.rest_a, c.rest_b)) + "</tr>")
    body.append("</table><div>")
    for c in cmp.curves:
        ya, yb = a.per_frame[c.name], b.per_frame[c.name]
        x = list(range(len(ya)))
        body.append(svg_plot(c.name, "frame", c.name.rsplit("/", 1)[-1], [("A", x, ya, False), ("B", x, yb, True)]))
    body.append("</div>")
    return ("<!DOCTYPE html><html><head><meta charset='utf-8'><title>" + html.escape(title)
            + "</title><style>body{font-family:sans-serif;max-width:1100px;margin:auto}svg{margin:4px}</style>"
            "</head><body>" + "".join(body) + "</body></html>")
