"""Collision geometry: a mesh split into a few convex pieces (what every physics engine wants).

``coacd`` (approximate convex decomposition, PyPI wheel) when it is installed; otherwise a
self-contained fallback that clusters surface samples with k-means and takes each cluster's convex
hull. The fallback over-covers concave regions more than CoACD does (a drawer's hollow inside fills
up unless it gets enough clusters) but always gives valid convex pieces.
"""

from __future__ import annotations

import numpy as np
import trimesh
from scipy.cluster.vq import kmeans2

from artitwin_core._errors import InputError

_MIN_HULL_VOLUME_M3 = 1e-9  # below this a hull is a sliver that engines reject


def _valid_hull(points: np.ndarray) -> trimesh.Trimesh | None:
    if len(points) < 4:
        return None
    try:
        hull = trimesh.convex.convex_hull(points)
    except Exception:  # qhull fails on coplanar / degenerate input: such a piece has no volume
        return None
    if not hull.is_volume or hull.volume < _MIN_HULL_VOLUME_M3:
        return None
    return hull


def _kmeans_hulls(mesh: trimesh.Trimesh, max_parts: int, seed: int) -> list[trimesh.Trimesh]:
    pts, _ = trimesh.sample.sample_surface(mesh, 20 * max(64, max_parts * 64), seed=seed)
    pts = np.concatenate([pts, mesh.vertices])
    k = int(min(max_parts, max(1, len(pts) // 16)))
    rng = np.random.default_rng(seed)
    _, lab = kmeans2(pts, k, minit="++", seed=rng)
    hulls = [_valid_hull(pts[lab == i]) for i in range(k)]
    return [h for h in hulls if h is not None]


def convex_decomposition(
    mesh: trimesh.Trimesh,
    *,
    method: str = "auto",
    max_parts: int = 16,
    threshold: float = 0.1,
    max_input_faces: int = 2000,
    seed: int = 0,
) -> list[trimesh.Trimesh]:
    """Convex pieces ``[trimesh.Trimesh]`` (same frame and units as ``mesh``) that cover it.

    Args:
        mesh: any triangle mesh (need not be watertight).
        method: ``"coacd"``, ``"kmeans"`` (fallback above) or ``"auto"`` (coacd if importable).
        max_parts: at most this many pieces.
        threshold: CoACD concavity threshold (smaller = more, tighter pieces).
        max_input_faces: the mesh is decimated to this many faces first (CoACD's run time grows
            with the face count; collision shapes need no detail).
        seed: fixes CoACD's and k-means' random choices.

    Returns:
        At least one convex piece (the whole mesh's convex hull if decomposition gave nothing).
    """
    if len(mesh.faces) == 0:
        raise InputError("convex_decomposition: the mesh has no faces (nothing was fused for this link).")
    if method not in ("auto", "coacd", "kmeans"):
        raise InputError(f"convex_decomposition: method {method!r}; use 'auto', 'coacd' or 'kmeans'.")
    if method == "auto":
        try:
            import coacd  # noqa: F401
            method = "coacd"
        except ImportError:
            method = "kmeans"
    work = mesh
    if len(mesh.faces) > max_input_faces:
        from artitwin_core.export._fuse import clean_mesh

        work = clean_mesh(mesh, max_faces=max_input_faces, min_component_fraction=0.0)
    pieces: list[trimesh.Trimesh] = []
    if method == "coacd":
        import coacd

        coacd.set_log_level("error")
        parts = coacd.run_coacd(
            coacd.Mesh(np.asarray(work.vertices, np.float64), np.asarray(work.faces, np.int32)),
            threshold=float(threshold),
            max_convex_hull=int(max_parts),
            preprocess_mode="auto",
            # A coarse manifold remesh and a shallow tree search: defaults took 30-100 s per fused
            # part on 2 cores; these take a few seconds and collision shapes need no detail.
            preprocess_resolution=30,
            mcts_iterations=40,
            mcts_nodes=10,
            mcts_max_depth=2,
            max_ch_vertex=64,
            seed=int(seed),
        )
        pieces = [h for h in (_valid_hull(np.asarray(v)) for v, _ in parts) if h is not None]
    else:
        pieces = _kmeans_hulls(work, max_parts, seed)
    if not pieces:
        hull = _valid_hull(np.asarray(mesh.vertices))
        if hull is None:
            raise InputError("convex_decomposition: the mesh is flat or degenerate; it encloses no volume.")
        pieces = [hull]
    return pieces
