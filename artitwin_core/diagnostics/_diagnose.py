"""Diagnose: which known effects explain the residual, in what order, and what structure is left.

Greedy forward selection (matching pursuit over effects): every applicable effect's signature is
measured on the current residual; the one that explains the largest share of its target is
enabled if that share is significant (at least ``min_explained`` of the target, and a gain of at
least ``min_gain_over_floor`` noise floors), and the search repeats on what is left. Noise models
(the ``depth-noise`` target) come after every significant systematic effect: a drifting pose or a
depth bias widens the residual's spread too. The first
round's signatures rank every effect; the enabled ones, in order, are the diagnosis. Whatever a
target still holds beyond ``structure_ratio`` noise floors is reported as unexplained structure,
with the variable it correlates with most (frame index, depth, image radius, joint state).
The enabled effects are then checked on frames they were not fitted on (``evaluate_heldout``).

A depth effect (``Effect.null_columns``: pose drift, depth scale and offset) can pass for the
twin's own geometry error, which is fixed in the world, when the camera sees different surfaces at
different times or distances. Such an effect counts as significant only when it also beats that
null on held-out frames (``surface_null_check``: a static per-surface correction, and the effect
fitted on what varies within a surface patch from frame to frame). When nothing is enabled and the depth residual
left is explained by the static correction, the conclusion says so: the twin needs more training,
not another effect.
"""

from __future__ import annotations

from dataclasses import dataclass, field, replace

import numpy as np

from artitwin_core._errors import InputError
from artitwin_core.diagnostics._config import DiagnoseConfig
from artitwin_core.diagnostics._heldout import HeldOut, evaluate_heldout
from artitwin_core.diagnostics._plugin import Effect, Signature, registered_effects
from artitwin_core.diagnostics._residuals import TARGETS, ResidualData, noise_floor, target_energy
from artitwin_core.diagnostics._surface_null import SurfaceNullCheck, surface_null_check

# Targets that measure a noise model, not a residual: their effects are enabled after the others.
NOISE_TARGETS = ("depth-noise",)
# Tolerance of the depth-noise model: a 5 % spread mismatch is "at the floor".
_DEPTH_NOISE_TOLERANCE = 0.05**2


@dataclass(frozen=True)
class Structure:
    """Residual left in one target after the enabled effects.

    Attributes:
        target: one of ``TARGETS``.
        energy: ``target_energy`` after the enabled effects.
        floor: its noise floor.
        correlations: ``{variable: eta^2}`` correlation ratio of the residual with each variable.
        world_fixed: (depth) share of it a static per-surface correction explains on held-out
            frames (NaN when not measured).
        twin_geometry: ``world_fixed`` reaches ``DiagnoseConfig.min_world_fixed``: the structure is
            the twin's own geometry error (train longer), not a missing effect.
    """

    target: str
    energy: float
    floor: float
    correlations: dict[str, float]
    world_fixed: float = float("nan")
    twin_geometry: bool = False

    @property
    def ratio(self) -> float:
        return self.energy / self.floor if self.floor > 0 else float("inf")


@dataclass(frozen=True)
class Diagnosis:
    """The answer of ``diagnose``.

    Attributes:
        ranking: every applicable effect's first-round signature, best explained fraction first.
        enabled: the effects selected in order, each signature measured when it was selected.
        energy_before, energy_after: ``{target: energy}`` before any and after all enabled effects.
        floors: ``{target: noise floor}``.
        significant: names of the ranked effects that passed the significance test in round one.
        remaining: targets that still hold structure above the floor.
        conclusion: the plain-language verdict, one line per finding.
        residual_after: the data with the enabled effects applied.
        heldout: the enabled effects refitted on training frames and scored on held-out ones
            (None when the check is off or the recording is too short).
        null_checks: each effect with ``null_columns`` that was significant in some round, against
            the twin-geometry null (``surface_null_check``), in the order checked.
    """

    ranking: list[Signature]
    enabled: list[Signature]
    energy_before: dict[str, float]
    energy_after: dict[str, float]
    floors: dict[str, float]
    significant: tuple[str, ...] = ()
    remaining: list[Structure] = field(default_factory=list)
    conclusion: list[str] = field(default_factory=list)
    residual_after: ResidualData | None = None
    heldout: HeldOut | None = None
    null_checks: list[SurfaceNullCheck] = field(default_factory=list)

    @property
    def no_effect_needed(self) -> bool:
        """Nothing enabled, and whatever structure is left is the twin's own geometry."""
        return not self.enabled and all(st.twin_geometry for st in self.remaining)


def _eta2(x: np.ndarray, y: np.ndarray, n_bins: int = 10) -> float:
    """Correlation ratio: the share of ``y``'s variance explained by bins of ``x`` (0..1)."""
    ok = np.isfinite(x) & np.isfinite(y)
    x, y = x[ok], y[ok]
    if x.size < 5 * n_bins or np.ptp(x) == 0 or np.var(y) == 0:
        return 0.0
    edges = np.unique(np.quantile(x, np.linspace(0, 1, n_bins + 1)))
    idx = np.clip(np.searchsorted(edges, x, side="right") - 1, 0, len(edges) - 2)
    counts = np.bincount(idx)
    means = np.bincount(idx, weights=y) / np.maximum(counts, 1)
    return float(np.sum(counts * (means - y.mean()) ** 2) / (y.size * np.var(y)))


def _correlations(data: ResidualData, target: str) -> dict[str, float]:
    """eta^2 of the signed residual and of its magnitude with each variable; the larger of the two."""
    out: dict[str, float] = {}

    def both(name, x, r):
        out[name] = max(_eta2(x, r), _eta2(x, np.abs(r)))

    if target == "photometric":
        r = data.rgb_residual().mean(-1)
        v = data.rgb_valid
        frame = np.broadcast_to(np.arange(v.shape[0])[:, None, None], v.shape)
        both("frame index", frame[v].astype(float), r[v])
        both("image radius", data.radius()[v], r[v])
        both("brightness", data.rgb_pred.mean(-1)[v], r[v])
    elif target in ("depth", "depth-noise"):
        r = data.depth_residual()
        ok = np.isfinite(r)
        frame = np.broadcast_to(np.arange(r.shape[0])[:, None, None], r.shape)
        both("frame index", frame[ok].astype(float), r[ok])
        both("depth", data.depth_pred[ok].astype(float), r[ok])
        t, h, w = r.shape
        u, vv = np.meshgrid(np.arange(w) - w / 2, np.arange(h) - h / 2)
        rad = np.broadcast_to(np.hypot(u, vv) / np.hypot(w / 2, h / 2), r.shape)
        both("image radius", rad[ok], r[ok])
    elif target == "joint-tracks":
        r = np.linalg.norm(data.track_residual(), axis=-1)
        ok = data.tracks_valid
        frame = np.broadcast_to(np.arange(ok.shape[0])[:, None], ok.shape)
        q = np.broadcast_to(data.tracks.q[:, None], ok.shape)
        out["frame index"] = _eta2(frame[ok].astype(float), r[ok])
        out["joint state"] = _eta2(q[ok], r[ok])
    return out


def _has_null(effect: Effect, data: ResidualData) -> bool:
    """The effect is checked against the twin-geometry null (it gives columns; the data has poses)."""
    return (type(effect).null_columns is not Effect.null_columns and data.has_depth and data.has_poses
            and data.depth_intrinsics is not None)


def _floor(data: ResidualData, target: str) -> float:
    f = noise_floor(data, target)
    return f + _DEPTH_NOISE_TOLERANCE if target == "depth-noise" else f


def _significant(sig: Signature, floor: float, cfg: DiagnoseConfig) -> bool:
    gain = sig.energy_before - sig.energy_after
    return bool(np.isfinite(gain) and sig.explained_fraction >= cfg.min_explained and gain >= cfg.min_gain_over_floor * floor)


def _signature(effect: Effect, data: ResidualData) -> Signature:
    """``effect.signature(data)``; a plugin that fails or answers nonsense is named in an InputError."""
    try:
        sig = effect.signature(data)
    except InputError:
        raise
    except Exception as exc:  # a user plugin's bug must name the plugin, not end in a numpy traceback
        raise InputError(
            f"effect {effect.name!r} ({type(effect).__module__}.{type(effect).__name__}) failed on the residuals: "
            f"{type(exc).__name__}: {exc}. Fix the plugin or leave it out of DiagnoseConfig.effects."
        ) from exc
    if not isinstance(sig, Signature) or not isinstance(sig.params, dict):
        raise InputError(
            f"effect {effect.name!r} returned {type(sig).__name__} from signature(); return a Signature "
            "(or override only fit and apply)."
        )
    return sig


def diagnose(
    data: ResidualData, effects: dict[str, Effect] | None = None, config: DiagnoseConfig | None = None
) -> Diagnosis:
    """Rank the effects by the residual they explain, enable the significant ones, report what is left.

    Args:
        data: predictions and measurements (``make_residual_data``).
        effects: ``{name: Effect}``; every registered effect when None.
        config: thresholds; ``DiagnoseConfig()`` when None.
    """
    cfg = config or DiagnoseConfig()
    pool = {n: e for n, e in (effects if effects is not None else registered_effects()).items() if e.applies(data)}
    targets = [t for t in TARGETS if np.isfinite(target_energy(data, t))]
    floors = {t: _floor(data, t) for t in targets}
    before = {t: target_energy(data, t) for t in targets}

    effects_by_name = dict(pool)
    current = data
    enabled: list[Signature] = []
    ranking: list[Signature] = []
    significant: tuple[str, ...] = ()
    null_checks: list[SurfaceNullCheck] = []
    every = cfg.heldout_every or 4
    kept: dict[str, Signature] = {}  # last round's signatures the enabled effect cannot have changed
    for round_ in range(cfg.max_rounds):
        sigs = [kept[n] if n in kept else _signature(e, current) for n, e in pool.items()]
        by_name = {s.name: s for s in sigs}
        sigs = [s for s in sigs if np.isfinite(s.explained_fraction) and s.target in floors]
        ok = {s.name for s in sigs if _significant(s, floors[s.target], cfg)}
        for s in sigs:
            effect = pool[s.name]
            if s.name in ok and _has_null(effect, current):
                check = surface_null_check(current, s.name, every, cfg.min_gain_over_null, cfg.min_gain_over_floor,
                                           columns=effect.null_columns)
                null_checks.append(check)
                if not check.accepted:
                    ok.discard(s.name)
        # Significant effects first: a large share of a residual already at the floor is no finding.
        # Among them, noise models last: a systematic error (a drifting pose, a depth bias) widens
        # the residual's spread too, so the noise is judged on what the systematic effects leave.
        sigs.sort(key=lambda s: (s.name not in ok, s.target in NOISE_TARGETS, -s.explained_fraction))
        if round_ == 0:
            ranking, significant = sigs, tuple(s.name for s in sigs if s.name in ok)
        best = sigs[0] if sigs and sigs[0].name in ok else None
        if best is None:
            break
        enabled.append(best)
        previous, current = current, pool.pop(best.name).apply(current, best.params)
        changed = current.changed_from(previous)
        kept = {n: by_name[n] for n, e in pool.items() if n in by_name and changed <= e.unaffected_by}

    after = {t: target_energy(current, t) for t in targets}
    # The floor after: an enabled noise model changes what "only noise left" means for depth.
    floors_after = {t: _floor(current, t) for t in targets}
    remaining = []
    for t in targets:
        if after[t] <= cfg.structure_ratio * floors_after[t]:
            continue
        st = Structure(t, after[t], floors_after[t], _correlations(current, t))
        if t == "depth" and current.has_poses and current.depth_intrinsics is not None:
            fixed = surface_null_check(current, "", every).null_fraction
            st = replace(st, world_fixed=fixed, twin_geometry=bool(fixed >= cfg.min_world_fixed))
        remaining.append(st)
    conclusion = []
    for s in enabled:
        conclusion.append(f"{s.name} explains {100 * s.explained_fraction:.0f}% of the {s.target} residual.")
    last_check = {c.name: c for c in null_checks}  # an effect checked in several rounds: its last word
    for c in last_check.values():
        if not c.accepted and c.name not in {s.name for s in enabled}:
            conclusion.append(
                f"{c.name} was not enabled: it explains no more than the twin's own geometry does (a static "
                f"per-surface correction, fixed in the world; on held-out frames it removes "
                f"{100 * max(c.gain_over_null, 0.0):.0f}% of what that correction leaves)."
            )
    for st in remaining:
        if st.twin_geometry:
            conclusion.append(
                f"The remaining {st.target} residual ({st.ratio:.1f}x the noise floor) is the twin's own geometry: "
                f"fixed in the world, a static per-surface correction explains {100 * st.world_fixed:.0f}% of it "
                "on held-out frames. Train the twin longer."
            )
            continue
        named = sorted(((v, k) for k, v in st.correlations.items() if v >= cfg.min_correlation), reverse=True)
        where = (f", correlated with {named[0][1]} (eta^2 = {named[0][0]:.2f})") if named else ""
        conclusion.append(
            f"Unexplained structure remains in the {st.target} residual ({st.ratio:.1f}x the noise floor){where}."
        )
    if not enabled and not remaining:
        conclusion.append("No effect needed: every residual is at the noise floor.")
    elif not enabled and all(st.twin_geometry for st in remaining):
        conclusion.insert(0, "No effect needed: the remaining residual is the twin's own geometry (fixed in the "
                             "world); train the twin longer.")
    elif not enabled:
        conclusion.insert(0, "No known effect explains a significant share of the residual.")
    heldout = (evaluate_heldout(data, [effects_by_name[s.name] for s in enabled], cfg.heldout_every)
               if cfg.heldout_every else None)
    if heldout is not None:
        for c in heldout.checks:
            conclusion.append(
                f"On held-out frames, {c.name} could not be refitted on the training frames ({c.failed})." if c.failed
                else f"On held-out frames, {c.name} takes {c.error} from {c.error_before:.4g} to {c.error_after:.4g}."
            )
    return Diagnosis(ranking, enabled, before, after, floors, significant, remaining, conclusion, current, heldout,
                     null_checks)
