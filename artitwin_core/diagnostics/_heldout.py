"""Held-out check of a diagnosis: refit the enabled effects on training frames, score unseen frames.

Every ``every``-th frame (starting at ``every // 2``) of the images and, separately, of the tracks
is held out; frames are interleaved rather than a contiguous tail so that joint effects, which grow
with the joint state, are scored inside the range of states they were fitted on. The training view
is the same ``ResidualData`` with its validity masks restricted to the training frames, so an
effect's ``fit`` sees only those; latent track points are re-solved on the training frames too.
Effects are then fitted in the diagnosis' order, each on what the previous ones left.

Global parameters (vignetting fall-off, depth scale and offset, depth-noise coefficients, screw
pitch, axis tilt, white-balance ratios) are fixed from training. Parameters that are inherently per
frame (the exposure gain of a frame) cannot be known for a frame never seen: ``Effect.transfer``
re-estimates them on each held-out frame with the global part fixed.

The score on held-out frames is, per block, the target energy and a plain error: RGB mean absolute
error (linear), depth mean absolute error (metres), depth negative log-likelihood under the noise
model sigma(z) (nats per pixel; the only error a noise model can change) and track RMS (metres).
"""

from __future__ import annotations

from dataclasses import dataclass, field, replace

import numpy as np

from artitwin_core.diagnostics._plugin import Effect
from artitwin_core.diagnostics._residuals import ResidualData, solve_points, target_energy

# The held-out error that tells whether an effect helps, per target it addresses.
ERROR_OF_TARGET = {
    "photometric": "rgb_mae_linear",
    "depth": "depth_mae_m",
    "depth-noise": "depth_nll_nats",
    "joint-tracks": "track_rms_m",
}


@dataclass(frozen=True)
class HeldOutCheck:
    """One enabled effect, refitted on training frames, scored on held-out frames.

    Attributes:
        name, target: the effect and the residual it targets.
        error: the held-out error that scores it (``ERROR_OF_TARGET[target]``).
        energy_before, energy_after: ``target_energy`` on held-out frames without and with it
            (the effects enabled before it are applied in both).
        error_before, error_after: that error on held-out frames without and with it.
        failed: why the refit failed on the training frames (then the numbers are NaN and the
            effect is left out of the held-out chain); empty when it ran.
    """

    name: str
    target: str
    error: str
    energy_before: float
    energy_after: float
    error_before: float
    error_after: float
    failed: str = ""


@dataclass(frozen=True)
class HeldOut:
    """The held-out check of a diagnosis.

    Attributes:
        image_frames: indices of the held-out RGB/depth frames.
        track_frames: indices of the held-out track frames.
        errors_before, errors_after: ``{error name: value}`` on held-out frames before any and after
            every enabled effect (names carry units: ``rgb_mae_linear``, ``depth_mae_m``,
            ``depth_nll_nats``, ``track_rms_m``).
        energy_before, energy_after: ``{target: energy}`` on held-out frames, same two states.
        checks: one per enabled effect, in the order they were enabled.
    """

    image_frames: tuple[int, ...]
    track_frames: tuple[int, ...]
    errors_before: dict[str, float]
    errors_after: dict[str, float]
    energy_before: dict[str, float]
    energy_after: dict[str, float]
    checks: list[HeldOutCheck] = field(default_factory=list)


def heldout_frames(n_frames: int, every: int) -> np.ndarray:
    """``[n_frames]`` bool, True for held-out frames: every ``every``-th, starting at ``every // 2``.
    All False when fewer than ``every`` frames (nothing left to hold out without starving the fit)."""
    held = np.zeros(n_frames, bool)
    if every >= 2 and n_frames >= every:
        held[every // 2 :: every] = True
    return held


def _restrict(data: ResidualData, base: ResidualData, images: np.ndarray | None, tracks: np.ndarray | None) -> ResidualData:
    """``data`` with ``base``'s validity masks limited to the frames set in ``images [T]`` / ``tracks [T2]``."""
    kw = {}
    if data.has_rgb:
        kw["rgb_valid"] = base.rgb_valid & images[:, None, None]
    if data.has_depth:
        kw["depth_valid"] = base.depth_valid & images[:, None, None]
    if data.has_tracks:
        kw["tracks_valid"] = base.tracks_valid & tracks[:, None]
    return replace(data, **kw)


def heldout_errors(view: ResidualData) -> dict[str, float]:
    """The plain errors of ``view`` over its valid pixels and tracks (one per block it holds)."""
    out: dict[str, float] = {}
    if view.has_rgb and view.rgb_valid.any():
        out["rgb_mae_linear"] = float(np.mean(np.abs(view.rgb_meas - view.rgb_pred)[view.rgb_valid]))
    if view.has_depth:
        r = view.depth_residual()
        ok = np.isfinite(r)
        if ok.any():
            out["depth_mae_m"] = float(np.mean(np.abs(r[ok])))
            a, b = view.depth_sigma
            sigma = np.maximum(a + b * view.depth_pred[ok].astype(np.float64) ** 2, 1e-6)
            out["depth_nll_nats"] = float(np.mean(0.5 * np.log(2 * np.pi * sigma**2) + 0.5 * (r[ok] / sigma) ** 2))
    if view.has_tracks and view.tracks_valid.any():
        d2 = np.sum(np.nan_to_num(view.track_residual()) ** 2, -1)[view.tracks_valid]
        out["track_rms_m"] = float(np.sqrt(np.mean(d2)))
    return out


def _energies(view: ResidualData, targets) -> dict[str, float]:
    out = {t: target_energy(view, t) for t in targets}
    return {t: e for t, e in out.items() if np.isfinite(e)}


def evaluate_heldout(data: ResidualData, effects: list[Effect], every: int = 4) -> HeldOut | None:
    """Refit ``effects`` (in order) on the training frames of ``data`` and score the held-out ones.

    Args:
        data: the residual data the diagnosis ran on.
        effects: the enabled effects, in the order the diagnosis enabled them.
        every: hold out every ``every``-th frame (see ``heldout_frames``).

    Returns:
        ``HeldOut``, or None when neither images nor tracks have enough frames to hold any out.
    """
    n_img = data.rgb_pred.shape[0] if data.has_rgb else data.depth_pred.shape[0] if data.has_depth else 0
    n_trk = data.tracks_obs.shape[0] if data.has_tracks else 0
    held_img, held_trk = heldout_frames(n_img, every), heldout_frames(n_trk, every)
    if not held_img.any() and not held_trk.any():
        return None
    train = _restrict(data, data, ~held_img, ~held_trk)
    if train.has_tracks:
        # The latent closed-state points are a fitted quantity: they must not see the held-out frames.
        tm = train.tracks
        points = solve_points(tm.motions, train.tracks_obs, train.tracks_valid, tm.points_closed)
        train = replace(train, tracks=replace(tm, points_closed=points))

    def view(d: ResidualData) -> ResidualData:
        return _restrict(d, data, held_img, held_trk)

    targets = sorted({e.target for e in effects} | set(ERROR_OF_TARGET))
    first = view(train)
    errors_before, energy_before = heldout_errors(first), _energies(first, targets)
    checks = []
    current = train
    for effect in effects:
        err = ERROR_OF_TARGET[effect.target]
        try:
            params, _ = effect.fit(current)
            params = effect.transfer(params, current, view(current))
            nxt = effect.apply(current, params)
        except Exception as exc:  # noqa: BLE001 - the fit ran on all frames; fewer frames may starve it
            # The check must not sink the diagnosis it checks: the failure is reported, not raised.
            nan = float("nan")
            checks.append(HeldOutCheck(effect.name, effect.target, err, nan, nan, nan, nan,
                                       f"{type(exc).__name__}: {exc}"))
            continue
        v0, v1 = view(current), view(nxt)
        e0, e1 = heldout_errors(v0), heldout_errors(v1)
        checks.append(HeldOutCheck(effect.name, effect.target, err, target_energy(v0, effect.target),
                                   target_energy(v1, effect.target), e0.get(err, float("nan")),
                                   e1.get(err, float("nan"))))
        current = nxt
    last = view(current)
    return HeldOut(tuple(np.flatnonzero(held_img).tolist()), tuple(np.flatnonzero(held_trk).tolist()),
                   errors_before, heldout_errors(last), energy_before, _energies(last, targets), checks)
