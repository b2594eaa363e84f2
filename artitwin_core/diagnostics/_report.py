"""The HTML report of a diagnosis: one self-contained file, plots as inline SVG, images as PNG data URIs.

No plotting library: the plots are polylines on a linear axis box, which is all the evidence plots
and the per-frame error curves need. Residual maps are colour-mapped with numpy and encoded by PIL.
"""

from __future__ import annotations

import base64
import html
import io
from pathlib import Path

import numpy as np
from PIL import Image

from artitwin_core.diagnostics._diagnose import Diagnosis
from artitwin_core.diagnostics._plugin import Evidence
from artitwin_core.diagnostics._residuals import ResidualData, per_frame_errors

_COLOURS = ("#1f77b4", "#d62728", "#2ca02c", "#9467bd", "#ff7f0e", "#17becf")
_W, _H, _PAD = 460, 240, 46


def _fmt(v: float) -> str:
    return "nan" if not np.isfinite(v) else f"{v:.3g}"


def svg_plot(title: str, x_label: str, y_label: str, series: list[tuple[str, list, list, bool]]) -> str:
    """A line plot as an SVG string. ``series``: ``(name, x [K], y [K], dashed)``; NaNs break lines."""
    xs = np.concatenate([np.asarray(x, float) for _, x, _, _ in series]) if series else np.zeros(0)
    ys = np.concatenate([np.asarray(y, float) for _, _, y, _ in series]) if series else np.zeros(0)
    ok = np.isfinite(xs) & np.isfinite(ys)
    if not ok.any():
        return f"<p><em>{html.escape(title)}: nothing to plot.</em></p>"
    x0, x1 = float(xs[ok].min()), float(xs[ok].max())
    y0, y1 = float(min(ys[ok].min(), 0.0) if ys[ok].min() >= 0 else ys[ok].min()), float(ys[ok].max())
    x1, y1 = (x1 if x1 > x0 else x0 + 1.0), (y1 if y1 > y0 else y0 + 1.0)

    def px(x, y):
        return (_PAD + (x - x0) / (x1 - x0) * (_W - 1.5 * _PAD), _H - _PAD + (y0 - y) / (y1 - y0) * (_H - 1.6 * _PAD))

    parts = [f'<svg xmlns="http://www.w3.org/2000/svg" width="{_W}" height="{_H}" font-size="11" font-family="sans-serif">',
             f'<text x="{_W / 2}" y="14" text-anchor="middle" font-weight="bold">{html.escape(title)}</text>',
             f'<rect x="{_PAD}" y="{0.6 * _PAD}" width="{_W - 1.5 * _PAD}" height="{_H - 1.6 * _PAD}" fill="none" stroke="#888"/>',
             f'<text x="{_W / 2}" y="{_H - 6}" text-anchor="middle">{html.escape(x_label)}</text>',
             f'<text x="12" y="{_H / 2}" text-anchor="middle" transform="rotate(-90 12 {_H / 2})">{html.escape(y_label)}</text>']
    for v, anchor in ((x0, "start"), (x1, "end")):
        parts.append(f'<text x="{px(v, y0)[0]:.1f}" y="{_H - _PAD + 13}" text-anchor="{anchor}">{_fmt(v)}</text>')
    for v in (y0, y1):
        parts.append(f'<text x="{_PAD - 3}" y="{px(x0, v)[1] + 4:.1f}" text-anchor="end">{_fmt(v)}</text>')
    for i, (name, x, y, dashed) in enumerate(series):
        colour = _COLOURS[i % len(_COLOURS)]
        x, y = np.asarray(x, float), np.asarray(y, float)
        runs, run = [], []
        for xi, yi in zip(x, y, strict=True):
            if np.isfinite(xi) and np.isfinite(yi):
                run.append("{:.1f},{:.1f}".format(*px(xi, yi)))
            elif run:
                runs.append(run)
                run = []
        runs.append(run)
        dash = ' stroke-dasharray="5,3"' if dashed else ""
        for r in runs:
            if len(r) == 1:
                cx, cy = r[0].split(",")
                parts.append(f'<circle cx="{cx}" cy="{cy}" r="2" fill="{colour}"/>')
            elif r:
                parts.append(f'<polyline points="{" ".join(r)}" fill="none" stroke="{colour}" stroke-width="1.5"{dash}/>')
        parts.append(f'<text x="{_W - 0.5 * _PAD - 4}" y="{0.6 * _PAD + 14 + 13 * i}" text-anchor="end" '
                     f'fill="{colour}">{html.escape(name)}</text>')
    parts.append("</svg>")
    return "".join(parts)


def evidence_svg(ev: Evidence) -> str:
    """The evidence plot of one effect: measured rows solid, the fitted model dashed."""
    y, model = np.asarray(ev.y, float), np.asarray(ev.model, float)
    y, model = np.atleast_2d(y), np.atleast_2d(model)
    names = ev.series or ("measured",)
    series = []
    for i in range(y.shape[0]):
        label = names[i] if i < len(names) else f"row {i}"
        series.append((label, ev.x, y[i], False))
        series.append((f"{label} model", ev.x, model[i], True))
    return svg_plot(ev.title, ev.x_label, ev.y_label, series)


def heatmap_png(values: np.ndarray, vmax: float, signed: bool) -> bytes:
    """``[H, W]`` values -> PNG bytes. Signed: blue (negative) - white - red; else black - yellow.
    NaN is grey."""
    v = np.asarray(values, np.float64)
    nan = ~np.isfinite(v)
    x = np.clip(np.nan_to_num(v) / max(vmax, 1e-12), -1.0, 1.0)
    if signed:
        r = np.where(x > 0, 1.0, 1.0 + x)
        g = 1.0 - np.abs(x)
        b = np.where(x < 0, 1.0, 1.0 - x)
    else:
        x = np.abs(x)
        r, g, b = np.clip(2 * x, 0, 1), np.clip(2 * x - 0.5, 0, 1), np.clip(3 * x - 2, 0, 1)
    img = np.stack([r, g, b], -1)
    img[nan] = 0.5
    buf = io.BytesIO()
    Image.fromarray((img * 255).astype(np.uint8)).save(buf, format="PNG")
    return buf.getvalue()


def _img(png: bytes, caption: str) -> str:
    data = base64.b64encode(png).decode("ascii")
    return (f'<figure><img src="data:image/png;base64,{data}" style="width:256px;image-rendering:pixelated"/>'
            f"<figcaption>{html.escape(caption)}</figcaption></figure>")


def residual_maps(before: ResidualData, after: ResidualData, n_frames: int = 3) -> list[tuple[str, bytes]]:
    """``(caption, PNG)`` residual maps before and after the enabled effects, worst frames first."""
    out = []
    curves = per_frame_errors(before)
    if before.has_rgb:
        worst = np.argsort(-np.nan_to_num(curves["rgb_rms"], nan=-1.0))[:n_frames]
        rb, ra = before.rgb_residual().mean(-1), after.rgb_residual().mean(-1)
        vmax = float(np.quantile(np.abs(rb[before.rgb_valid]), 0.99)) if before.rgb_valid.any() else 1.0
        for t in worst:
            out.append((f"RGB residual (measured - predicted, linear), frame {t}, before; +-{vmax:.3g}",
                        heatmap_png(np.where(before.rgb_valid[t], rb[t], np.nan), vmax, True)))
            out.append((f"RGB residual, frame {t}, after the enabled effects", heatmap_png(
                np.where(after.rgb_valid[t], ra[t], np.nan), vmax, True)))
    if before.has_depth:
        worst = np.argsort(-np.nan_to_num(curves["depth_rms_m"], nan=-1.0))[:n_frames]
        db, da = before.depth_residual(), after.depth_residual()
        vmax = float(np.nanquantile(np.abs(db), 0.99)) if np.isfinite(db).any() else 1.0
        for t in worst:
            out.append((f"depth residual (m), frame {t}, before; +-{vmax:.3g} m", heatmap_png(db[t], vmax, True)))
            out.append((f"depth residual (m), frame {t}, after", heatmap_png(da[t], vmax, True)))
    return out


def _params_text(params: dict) -> str:
    """Scalar parameters in full; long lists summarised (per-frame gains are in the JSON)."""
    bits = []
    for k, v in params.items():
        if isinstance(v, int | float):
            bits.append(f"{k}={v:.4g}")
        elif isinstance(v, list) and len(v) <= 3 and all(isinstance(x, int | float) for x in v):
            bits.append(f"{k}=[{', '.join(f'{x:.3g}' for x in v)}]")
    return ", ".join(bits)


def _heldout_html(dg: Diagnosis) -> str:
    """The held-out table: errors on frames the enabled effects were not fitted on, before and after."""
    h = dg.heldout
    if h is None:
        return "<p><em>No held-out check (too few frames, or heldout_every = 0).</em></p>"
    rows = [f"<tr><td>{html.escape(k)}</td><td>{_fmt(v)}</td><td>{_fmt(h.errors_after.get(k, np.nan))}</td></tr>"
            for k, v in h.errors_before.items()]
    rows += [f"<tr><td>{html.escape(t)} energy</td><td>{_fmt(v)}</td><td>{_fmt(h.energy_after.get(t, np.nan))}</td></tr>"
             for t, v in h.energy_before.items()]
    return (f"<h3>Held-out frames</h3><p>Images {list(h.image_frames)}, tracks {list(h.track_frames)} are held out; "
            "the enabled effects are refitted on the other frames and scored on these. Global parameters "
            "(white-balance ratios, vignetting fall-off, depth scale and offset, depth-noise coefficients, pitch, "
            "tilt) come from the training frames; a per-frame parameter (a frame's exposure gain) cannot, and is "
            "re-estimated on each held-out frame with the global part fixed. Errors: rgb_mae_linear (linear RGB), "
            "depth_mae_m (metres), depth_nll_nats (per pixel, under the depth-noise model), track_rms_m (metres).</p>"
            "<table border=1 cellpadding=3 style='border-collapse:collapse'><tr><th>held-out</th><th>before</th>"
            "<th>after the enabled effects</th></tr>" + "".join(rows) + "</table>")


def render_html(sections: list[tuple[str, Diagnosis, ResidualData]], title: str = "ArtiTwin diagnosis") -> str:
    """The report for one or more diagnoses (e.g. the static recording and each joint's tracks).

    Args:
        sections: ``(heading, diagnosis, the data it was run on)``.
        title: the page title.
    """
    body = [f"<h1>{html.escape(title)}</h1>"]
    for heading, dg, data in sections:
        after = dg.residual_after if dg.residual_after is not None else data
        body.append(f"<h2>{html.escape(heading)}</h2><ul>")
        body += [f"<li>{html.escape(line)}</li>" for line in dg.conclusion]
        body.append("</ul><h3>Effects, ranked by the residual they explain</h3>")
        body.append("<table border=1 cellpadding=3 style='border-collapse:collapse'><tr><th>#</th><th>effect</th>"
                    "<th>target</th><th>explained</th><th>energy before</th><th>energy after</th><th>significant</th>"
                    "<th>enabled</th><th>held-out energy before</th><th>held-out energy after</th>"
                    "<th>held-out error</th><th>held-out error before</th><th>held-out error after</th>"
                    "<th>parameters</th></tr>")
        enabled = {s.name for s in dg.enabled}
        checks = {c.name: c for c in dg.heldout.checks} if dg.heldout is not None else {}
        for i, s in enumerate(dg.ranking):
            c = checks.get(s.name)
            held = (f"<td>{_fmt(c.energy_before)}</td><td>{_fmt(c.energy_after)}</td><td>{c.error}</td>"
                    f"<td>{_fmt(c.error_before)}</td><td>{_fmt(c.error_after)}</td>") if c else "<td></td>" * 5
            body.append(
                f"<tr><td>{i + 1}</td><td>{html.escape(s.name)}</td><td>{s.target}</td>"
                f"<td>{100 * s.explained_fraction:.1f}%</td><td>{_fmt(s.energy_before)}</td><td>{_fmt(s.energy_after)}</td>"
                f"<td>{'yes' if s.name in dg.significant else 'no'}</td><td>{'yes' if s.name in enabled else ''}</td>"
                f"{held}<td>{html.escape(_params_text(s.params))}</td></tr>"
            )
        body.append("</table><h3>Residual energy per target</h3><table border=1 cellpadding=3 "
                    "style='border-collapse:collapse'><tr><th>target</th><th>before</th><th>after</th><th>noise floor</th></tr>")
        for t, e in dg.energy_before.items():
            body.append(f"<tr><td>{t}</td><td>{_fmt(e)}</td><td>{_fmt(dg.energy_after.get(t, np.nan))}</td>"
                        f"<td>{_fmt(dg.floors.get(t, np.nan))}</td></tr>")
        body.append("</table>")
        body.append(_heldout_html(dg))
        body.append("<h3>Error over time</h3><div>")
        cb, ca = per_frame_errors(data), per_frame_errors(after)
        for name, curve in cb.items():
            frames = list(range(len(curve)))
            body.append(svg_plot(f"{name} per frame", "frame", name,
                                 [("before", frames, curve.tolist(), False), ("after", frames, ca[name].tolist(), True)]))
        body.append("</div>")
        shown = [s for s in dg.enabled if s.evidence is not None] or [s for s in dg.ranking[:1] if s.evidence is not None]
        if shown:
            body.append("<h3>Evidence</h3><div>")
            body += [evidence_svg(s.evidence) for s in shown]
            body.append("</div>")
        maps = residual_maps(data, after)
        if maps:
            body.append("<h3>Residual maps, worst frames first</h3><div style='display:flex;flex-wrap:wrap'>")
            body += [_img(png, cap) for cap, png in maps]
            body.append("</div>")
    return ("<!DOCTYPE html><html><head><meta charset='utf-8'><title>" + html.escape(title)
            + "</title><style>body{font-family:sans-serif;max-width:1100px;margin:auto}svg{margin:4px}"
            "figure{margin:4px;font-size:11px;width:260px}</style></head><body>" + "".join(body) + "</body></html>")


def write_html_report(path: str | Path, sections: list[tuple[str, Diagnosis, ResidualData]],
                      title: str = "ArtiTwin diagnosis") -> Path:
    """Write ``render_html(sections, title)`` to ``path``; returns the path."""
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    path.write_text(render_html(sections, title), encoding="utf-8")
    return path
