"""Stage IV: articulation-conditioned optimisation and articulated rendering.

``articulate(canonical, static, static_poses, dynamic, dynamic_poses, masks, joints)`` labels the
canonical Gaussians (background, interior, part k) from the part masks and the joints, seeds
Gaussians where the opening part reveals unseen surface, trains interior and part Gaussians on
the dynamic frames with the parts moved to each frame's joint state (phase I), then everything
on both recordings (phase II), and reports held-out PSNR. ``render_twin`` renders the result at
any joint state and viewpoint, with each part's brightness curve over its joint state
(``PartAppearance``: a turning part changes its angle to the light); ``world_from_part`` is the part's rigid motion at state q.
"""

from artitwin_core.articulation._appearance import PartAppearance
from artitwin_core.articulation._config import ArticulationConfig, PartitionConfig
from artitwin_core.articulation._kinematics import (
    TwinRenderer,
    articulate_params,
    articulate_tensors,
    part_motions,
    quat_multiply,
    render_twin,
    world_from_part,
)
from artitwin_core.articulation._optimize import ArticulatedViews, ArticulationState, evaluate_psnr
from artitwin_core.articulation._partition import PartitionVotes, partition_gaussians, surface_hits
from artitwin_core.articulation._pipeline import ArticulationResult, articulate, dynamic_views, label_counts

__all__ = [
    "ArticulatedViews",
    "ArticulationConfig",
    "ArticulationResult",
    "ArticulationState",
    "PartAppearance",
    "PartitionConfig",
    "PartitionVotes",
    "TwinRenderer",
    "articulate",
    "articulate_params",
    "articulate_tensors",
    "dynamic_views",
    "evaluate_psnr",
    "label_counts",
    "part_motions",
    "partition_gaussians",
    "quat_multiply",
    "render_twin",
    "surface_hits",
    "world_from_part",
]
