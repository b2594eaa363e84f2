"""Articulated poses: where each part is at joint state q, and the twin rendered there.

A part's motion is the joint's one-parameter subgroup of SE(3) (``artitwin_core.joints``):
rotation about the axis line through the pivot (revolute), translation along the axis
(prismatic), or both with ``pitch`` metres per radian (screw). Gaussians labelled
``LABEL_PART + k`` move rigidly with joint k: centres by ``R x + t`` and rotations by
``q_R * q``; background and interior Gaussians stay. Spherical-harmonic coefficients are not
rotated (view-dependent colour of a moved part is evaluated in the canonical orientation).
Given a :class:`PartAppearance`, part colours are scaled by the part's gain at ``q``.
"""

from __future__ import annotations

from collections.abc import Sequence

import numpy as np
import torch

from artitwin_core._errors import InputError
from artitwin_core.articulation._appearance import PartAppearance, apply_part_gains
from artitwin_core.gaussians import LABEL_PART, GaussianParams
from artitwin_core.geometry import matrix_to_quat_wxyz
from artitwin_core.joints import Joint, joint_transforms
from artitwin_core.reconstruction import ModelRenderer


def world_from_part(joint: Joint, q: float | np.ndarray) -> np.ndarray:
    """``[4, 4]`` (or ``[T, 4, 4]`` for ``q [T]``) float64 motion of the part at state ``q``.

    Maps a point of the part in the closed (canonical, ``q = 0``) state to its position at
    ``q`` (radians for revolute and screw, metres for prismatic).
    """
    qa = np.asarray(q, dtype=np.float64)
    out = joint_transforms(joint.joint_type, joint.axis, joint.pivot, np.atleast_1d(qa), joint.pitch)
    return out[0] if qa.ndim == 0 else out


def part_motions(joints: Sequence[Joint], q_per_joint: Sequence[float]) -> np.ndarray:
    """``[K, 4, 4]`` float64 ``world_from_part`` of every joint at its state."""
    q = np.asarray(q_per_joint, dtype=np.float64).reshape(-1)
    if len(q) != len(joints):
        raise InputError(
            f"articulation: {len(q)} joint states given for {len(joints)} joints; give one per joint."
        )
    if not len(joints):
        return np.zeros((0, 4, 4))
    return np.stack([world_from_part(j, float(v)) for j, v in zip(joints, q, strict=True)])


def quat_multiply(a: torch.Tensor, b: torch.Tensor) -> torch.Tensor:
    """Hamilton product ``a * b`` of wxyz quaternions ``[..., 4]`` (rotation b, then a)."""
    aw, ax, ay, az = a.unbind(-1)
    bw, bx, by, bz = b.unbind(-1)
    return torch.stack([
        aw * bw - ax * bx - ay * by - az * bz,
        aw * bx + ax * bw + ay * bz - az * by,
        aw * by - ax * bz + ay * bw + az * bx,
        aw * bz + ax * by - ay * bx + az * bw,
    ], dim=-1)  # fmt: skip


def motion_tables(motions: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Per-label rigid motions from ``[..., K, 4, 4]`` ``world_from_part``: rotations
    ``[..., L, 3, 3]``, translations ``[..., L, 3]`` and wxyz quaternions ``[..., L, 4]`` float64,
    ``L = LABEL_PART + K`` (background and interior rows are the identity)."""
    motions = np.asarray(motions, np.float64)
    lead, k = motions.shape[:-3], motions.shape[-3]
    table = np.broadcast_to(np.eye(4), (*lead, LABEL_PART + k, 4, 4)).copy()
    table[..., LABEL_PART:, :, :] = motions
    return table[..., :3, :3].copy(), table[..., :3, 3].copy(), matrix_to_quat_wxyz(table[..., :3, :3])


def move_by_label(
    means: torch.Tensor,
    quats_wxyz: torch.Tensor,
    labels: torch.Tensor,
    rot: torch.Tensor,
    trans: torch.Tensor,
    quat: torch.Tensor,
) -> tuple[torch.Tensor, torch.Tensor]:
    """Move every Gaussian by its label's row of ``rot [L, 3, 3]``, ``trans [L, 3]`` and ``quat
    [L, 4]`` (from :func:`motion_tables`, on the means' device and dtype); labels ``>= L`` stay."""
    n_labels = int(rot.shape[0])
    lab = labels.long()
    idx = torch.where(lab >= n_labels, 0, lab.clamp(0, n_labels - 1))  # unknown parts stay
    moved = torch.einsum("nij,nj->ni", rot[idx], means) + trans[idx]
    return moved, quat_multiply(quat[idx], quats_wxyz)


def articulate_tensors(
    means: torch.Tensor, quats_wxyz: torch.Tensor, labels: torch.Tensor, motions: np.ndarray | torch.Tensor
) -> tuple[torch.Tensor, torch.Tensor]:
    """Move the part Gaussians, differentiably in ``means`` and ``quats_wxyz``.

    Args:
        means: ``[N, 3]`` canonical centres, metres.
        quats_wxyz: ``[N, 4]`` canonical rotations.
        labels: ``[N]`` integer labels (``LABEL_PART + k`` moves with ``motions[k]``).
        motions: ``[K, 4, 4]`` ``world_from_part`` per joint.

    Returns:
        means ``[N, 3]`` and quats ``[N, 4]`` at the joint states, on the means' device. (A trainer
        that renders the same states again builds :func:`motion_tables` on its device once.)
    """
    m = motions.detach().cpu().numpy() if isinstance(motions, torch.Tensor) else np.asarray(motions)
    if int(m.shape[0]) == 0:
        return means, quats_wxyz
    dev, dtype = means.device, means.dtype
    rot, trans, quat = (torch.as_tensor(a).to(device=dev, dtype=dtype) for a in motion_tables(m))
    return move_by_label(means, quats_wxyz, labels, rot, trans, quat)


def articulate_params(
    params: GaussianParams,
    joints: Sequence[Joint],
    q_per_joint: Sequence[float],
    appearance: PartAppearance | None = None,
) -> GaussianParams:
    """``params`` with every part-k Gaussian moved to joint k's state ``q_per_joint[k]`` (and its
    colour scaled by ``appearance``'s gain there, when given)."""
    motions = part_motions(joints, q_per_joint)
    sh = params.sh
    if appearance is not None and appearance.num_parts:
        if appearance.num_parts != len(joints):
            raise InputError(
                f"articulate_params: the appearance has {appearance.num_parts} part curves for {len(joints)} "
                "joints; use the appearance articulated with these joints."
            )
        log_g = torch.from_numpy(np.log(appearance.gains(q_per_joint)))
        with torch.no_grad():
            sh = apply_part_gains(
                torch.from_numpy(np.asarray(params.sh, np.float32)),
                torch.from_numpy(np.asarray(params.labels)),
                log_g,
            ).numpy()
    with torch.no_grad():
        m, q = articulate_tensors(
            torch.from_numpy(np.asarray(params.means, np.float64)),
            torch.from_numpy(np.asarray(params.quats_wxyz, np.float64)),
            torch.from_numpy(np.asarray(params.labels)),
            motions,
        )
    return GaussianParams(
        means=m.numpy().astype(np.float32),
        quats_wxyz=q.numpy().astype(np.float32),
        log_scales=params.log_scales,
        opacity_logits=params.opacity_logits,
        sh=sh,
        labels=params.labels,
    )


class TwinRenderer:
    """The labelled twin on the device ``backend`` resolves to (copied there once), rendered at
    any joint states from any pinhole camera: what :func:`render_twin` does for many frames.

    Args:
        params: the labelled Gaussians in the canonical (closed) state.
        joints: one joint per part, in label order (part k = ``joints[k]``).
        background: RGB in [0, 1] behind everything.
        backend: ``"auto"`` (CUDA with gsplat when present, else CPU), ``"cpu"``, ``"reference"``, ``"cuda"``.
        appearance: the parts' brightness curves; None renders closed-state colours.
    """

    def __init__(
        self,
        params: GaussianParams,
        joints: Sequence[Joint],
        *,
        background: Sequence[float] = (0.0, 0.0, 0.0),
        backend: str = "auto",
        appearance: PartAppearance | None = None,
    ) -> None:
        if appearance is not None and appearance.num_parts and appearance.num_parts != len(joints):
            raise InputError(
                f"render_twin: the appearance has {appearance.num_parts} part curves for {len(joints)} "
                "joints; use the appearance articulated with these joints."
            )
        self.model = ModelRenderer(params, background=background, backend=backend)
        self.joints = list(joints)
        self.appearance = appearance
        self.labels = torch.from_numpy(np.asarray(params.labels).astype(np.int64)).to(self.model.device)

    def render(
        self, q_per_joint: Sequence[float], world_from_camera: np.ndarray, intrinsics: Sequence[float], width: int, height: int
    ) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """rgb ``[H, W, 3]``, expected depth ``[H, W]`` (metres, 0 where empty), alpha ``[H, W]``,
        with part k at ``q_per_joint[k]`` (see :func:`render_twin`)."""
        m = self.model
        with torch.no_grad():
            motions = part_motions(self.joints, q_per_joint)
            means, quats = articulate_tensors(m.means, m.quats_wxyz, self.labels, motions)
            sh = m.sh
            if self.appearance is not None and self.appearance.num_parts:
                log_g = torch.from_numpy(np.log(self.appearance.gains(q_per_joint))).to(m.device)
                sh = apply_part_gains(sh, self.labels, log_g)
        return m.render(world_from_camera, intrinsics, width, height, means=means, quats_wxyz=quats, sh=sh)


def render_twin(
    params: GaussianParams,
    joints: Sequence[Joint],
    q_per_joint: Sequence[float],
    world_from_camera: np.ndarray,
    intrinsics: Sequence[float],
    width: int,
    height: int,
    *,
    background: Sequence[float] = (0.0, 0.0, 0.0),
    backend: str = "auto",
    appearance: PartAppearance | None = None,
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Render the twin at any joint state from any pinhole camera (many frames:
    :class:`TwinRenderer` copies the twin to the device once).

    Args:
        params: the labelled Gaussians in the canonical (closed) state.
        joints: one joint per part, in label order (part k = ``joints[k]``).
        q_per_joint: ``[K]`` joint states, radians or metres.
        world_from_camera: ``[4, 4]`` camera pose in the canonical frame, OpenCV axes, metres.
        intrinsics: ``(fx, fy, cx, cy)`` pixels.
        width, height: image size, pixels.
        appearance: the parts' brightness curves (``ArticulationResult.appearance``); None
            renders every part with its closed-state colours.

    Returns:
        rgb ``[H, W, 3]`` float32 in [0, 1], expected depth ``[H, W]`` float32 metres (0 where
        nothing is rendered), alpha ``[H, W]`` float32.
    """
    part_motions(joints, q_per_joint)  # the state count is checked before anything is copied
    renderer = TwinRenderer(params, joints, background=background, backend=backend, appearance=appearance)
    return renderer.render(q_per_joint, world_from_camera, intrinsics, width, height)
