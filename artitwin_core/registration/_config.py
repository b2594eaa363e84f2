"""Hyperparameters of registering the dynamic recording onto the canonical frame
(:class:`RegistrationConfig`) and of fitting its pose drift (:class:`SessionDriftConfig`).
"""

from __future__ import annotations

from dataclasses import dataclass


@dataclass(frozen=True)
class RegistrationConfig:
    """Hyperparameters of :func:`register_recordings`.

    Attributes:
        max_depth_m: depth beyond this is ignored (LiDAR noise grows with range).
        min_confidence: keep depth pixels whose ARKit confidence is at least this (0 keeps all).
        pixel_stride: use every n-th depth pixel each way when fusing clouds.
        early_frame_weight: the first third of the dynamic frames (part most likely still closed,
            hand not yet in view) keep all their points; the rest keep ``1 / early_frame_weight``
            of them, so the moved part and the hand weigh less in the fused cloud.
        yaw_step_deg: step of the exhaustive yaw sweep about gravity (degrees).
        grid_cell_m: cell size of the top-down occupancy grids correlated for translation.
        height_bin_m: bin size of the height histograms correlated for the vertical offset.
        num_slabs: height slabs (channels) of the top-down grids.
        num_candidates: best yaws of the sweep whose translations are refined by ICP.
        peaks_per_yaw: translations (correlation peaks at least 0.5 m apart) tried per yaw:
            with partial overlap the highest peak can be a wall and floor slid along each other.
        icp_voxels_m: coarse-to-fine voxel sizes of the point-to-plane ICP (Tukey kernel).
        photometric_blur_rad: the photometric refinement's levels, coarse to fine: the Gaussian
            blur of the images (radians; times the focal length gives pixels). The coarse level
            reaches across a texture's features (about 5 cm at 2 m), the finest is precise.
            Empty skips the refinement.
        photometric_views: static images the dynamic points are compared with (evenly spaced).
        photometric_points: at most this many dynamic points (a fixed random subset).
        photometric_visibility_m: a static image sees a dynamic point when its depth there is
            within this (metres); pixels next to a depth jump larger than this are not used
            (their colour mixes two surfaces).
        photometric_max_step_m: the photometric refinement's result is kept only if it moved
            the registration less than this (metres): its coarse level reaches about 10 cm at
            room scale, and the point-to-plane stages can leave that much along a free direction.
        photometric_noise: the least standard deviation of a grey-level residual (grey levels
            in [0, 1]) where the texture is flat: what two recordings of one surface disagree
            by beyond their noise (a gain per pair of frames does not capture all of exposure
            and white balance, nor vignetting or the hand's shadow). Without it the residuals
            of untextured surfaces (most of them, and near zero) set the scale, every faint
            gradient weighs as much as a point-to-plane match, and a hand's shadow on a white
            cabinet pulls the result by about a centimetre (docs/accuracy.md).
        inlier_distance_m: a dynamic point is an inlier when its point-to-plane distance to the
            static surface is below this; sets the reported inlier fraction and residual.
        consistent_frame_margin: after the coarse stages, the fine stages use the dynamic frames
            whose share of points more than 5 cm from the static cloud is at most the lowest
            share plus this (frames where nothing has moved yet).
        min_consistent_frames: use at least this many frames (the most consistent ones).
        normal_noise_radii: normals are estimated within this many times the static cloud's
            surface noise (its spread about local planes), or 3 voxels if that is wider; 0
            keeps 3 voxels. Noisy depth tilts normals fitted over too small a patch, and
            point-to-plane ICP slides along the tilt.
        uncertainty_blocks: the result's covariance is a jackknife over this many spatial
            blocks of the dynamic cloud (each left out in turn, the finest ICP rerun); 0 skips
            it. Blocks, not points: the misfit of one surface (a wall slightly curved by the
            depth noise model, a door's edge) is shared by its points.
        max_tilt_deg: the two sessions' gravity may disagree by at most this (degrees): every
            ICP estimates yaw about gravity and translation only; then the finest is rerun with
            the tilt free, clamped to this bound, and its tilt kept only if significant (see
            ``tilt_test_blocks``); 0 keeps gravity exactly. ARKit's gravity is good to a few
            tenths of a degree.
        tilt_test_blocks: the free tilt is kept when it exceeds its block-jackknife uncertainty
            over this many spatial blocks of the dynamic cloud (see ``tilt_test_threshold``);
            below 3, it is always kept.
        tilt_test_threshold: the squared Mahalanobis distance of the tilt (two degrees of
            freedom) above which it is kept. Far above chi-square's 5.99: the blocks share the
            systematic misfit (a slightly curved wall, a door's edge), so the jackknife
            underestimates the uncertainty; synthetic scenes without tilt gave spurious tilts of
            0.07-0.3 deg at 6-46, and a real 0.3 deg tilt 113 (noisy) to 12000 (noise-free).
        score_views: hypotheses are scored with this many frames (evenly spaced) of each
            recording: the static ones' depth defines the space it saw through; the dynamic
            ones' points are tested, the early ones weighted as in ``early_frame_weight``.
        free_space_margin_m: a dynamic point counts against a hypothesis when a static depth ray
            passed more than this beyond it, and so does a dynamic ray that passed this far
            beyond a static point (metres): depth noise and edges stay within it.
        back_face_cos: a dynamic point on a static surface counts against a hypothesis, not
            for it, when the side the static cameras saw the surface from points away from the
            dynamic camera by more than ``acos(-back_face_cos)`` (0.25: 104 deg; grazing views
            stay out of it): the placement puts that camera behind the surface. None skips the
            test.
        texture_search_m: when the refined placement lays other texture on textured static
            surfaces (colour agreement under ``min_colour_agreement``), it is slid up to this
            far each way along the direction the geometry pins least, and the slide whose
            texture agrees is kept (metres; 0 skips the search). A close-up of a cabinet front
            leaves ICP anywhere along the front (8 cm off on generalization seed 26).
        texture_search_step_m: the slide's step (metres): under the texture's correlation
            length at the photometric refinement's coarsest blur, which takes it from there.
        distinct_hypothesis_m: two refined hypotheses that place the dynamic points within this
            RMS distance of each other (metres) are the same answer (the result lists one).
        min_overlap: refuse when, under the best hypothesis, fewer than this fraction of the
            dynamic points fall where the static recording looked (on its surfaces or in the
            space it saw through), unless the texture confirms it (below).
        min_textured_overlap, confirming_colour_agreement: an overlap down to
            ``min_textured_overlap`` is enough when the matched static surfaces carry texture
            (``min_colour_contrast``) and the dynamic recording's colours on them correlate at
            ``confirming_colour_agreement`` or more. Geometry alone, a fifth of the recording on
            a floor and a cabinet could sit elsewhere; its texture agreeing as well could not:
            wrong placements on the generalization scenes agreed at -0.34 to 0.36, right ones at
            0.65-0.82 (seed 12: 24 % overlap, 93 % of it on static surfaces, 0.82).
        min_inlier_ratio: refuse when, of the dynamic points where the static recording looked,
            fewer than this fraction lie on its surfaces (the rest sit in space it saw empty:
            the moved part and the hand, or a wrong placement). Half: more of the overlap
            contradicting the static recording than agreeing with it. The moved parts alone
            can take a fifth to a third of the overlap of a cabinet opened wide, which 0.8
            refused.
        rival_distance_m: the rival is the best hypothesis that places the dynamic points more
            than this RMS distance (metres) from the best one: another reading of the scene, not
            the best one slid a little along a wall.
        max_rival_ratio: refuse when the rival's support is at least this fraction of the
            best's (two different placements explain the data about equally well).
            A placement that lays other texture on textured surfaces than theirs
            (``min_colour_agreement``) is no rival.
        min_constraint: refuse when the best hypothesis' matched points pin its weakest
            direction less than this (see ``weakest_constraint``: 1/3 for three orthogonal
            planes in equal shares, 0 for one plane): the dynamic recording could slide.
            Not where the surfaces carry texture and the photometric refinement runs: the
            texture pins the slide, and the texture test checks the result.
        min_colour_agreement: refuse when, at the final placement, the texture on the matched
            surfaces agrees less than this (``HypothesisScore.colour_agreement``, a correlation:
            about 0 for unrelated textures, 0.4-0.9 for the right placement): the geometry
            matched surfaces of the same shape but not the same ones (a
            corner the static sweep never saw laid onto another corner of the room).
        min_colour_contrast: the texture test is made only when the static surfaces' texture
            varies by at least this much RMS about each surface's mean (intensity, 0-1): on
            plain surfaces the correlation is noise whatever the placement.
        refuse_unconvincing: raise :class:`RegistrationError` when a refusal test fails; False
            returns the best hypothesis anyway (its scores are in the result), for inspection.
    """

    max_depth_m: float = 4.5
    min_confidence: int = 1
    pixel_stride: int = 2
    early_frame_weight: float = 3.0
    yaw_step_deg: float = 2.0
    grid_cell_m: float = 0.05
    height_bin_m: float = 0.02
    num_slabs: int = 4
    num_candidates: int = 6
    peaks_per_yaw: int = 2
    icp_voxels_m: tuple[float, ...] = (0.08, 0.04, 0.02, 0.01)
    photometric_blur_rad: tuple[float, ...] = (0.024, 0.012, 0.006)
    photometric_views: int = 12
    photometric_points: int = 20000
    photometric_visibility_m: float = 0.03
    photometric_max_step_m: float = 0.15
    photometric_noise: float = 0.02
    inlier_distance_m: float = 0.02
    consistent_frame_margin: float = 0.03
    min_consistent_frames: int = 3
    normal_noise_radii: float = 6.0
    uncertainty_blocks: int = 10
    max_tilt_deg: float = 0.5
    tilt_test_blocks: int = 6
    tilt_test_threshold: float = 60.0
    score_views: int = 24
    free_space_margin_m: float = 0.05
    back_face_cos: float | None = 0.25
    texture_search_m: float = 0.3
    texture_search_step_m: float = 0.01
    distinct_hypothesis_m: float = 0.1
    min_overlap: float = 0.3
    min_textured_overlap: float = 0.15
    confirming_colour_agreement: float = 0.5
    min_inlier_ratio: float = 0.5
    rival_distance_m: float = 0.5
    max_rival_ratio: float = 0.7
    min_constraint: float = 0.003
    min_colour_agreement: float = 0.2
    min_colour_contrast: float = 0.02
    refuse_unconvincing: bool = True


@dataclass(frozen=True)
class SessionDriftConfig:
    """Hyperparameters of :func:`estimate_session_drift`.

    Attributes:
        gravity: gravity's direction in the canonical frame (the drift turns about it).
        mask_dilation_px: part and hand masks are grown by this many RGB pixels before they
            exclude depth and keypoints (their edges are a few pixels loose).
        max_association_m: a depth point further than this from the mesh surface ray-cast through
            its pixel is left out (surfaces the static sweep did not see, moved things).
        max_depth_m: depth beyond this is not used.
        min_confidence: ARKit depth confidence below this is not used.
        pixel_stride: every n-th depth pixel each way is used.
        frame_gaps: the recording's frames are matched with the frames this many later.
        static_neighbours: each frame is matched with this many static frames nearest to it.
        iterations: at most this many re-associations (each a weighted least-squares solve).
        jackknife_blocks: blocks of consecutive frames left out in turn for standard errors.
    """

    gravity: tuple[float, float, float] = (0.0, -1.0, 0.0)
    mask_dilation_px: int = 6
    max_association_m: float = 0.03
    max_depth_m: float = 4.5
    min_confidence: int = 1
    pixel_stride: int = 2
    frame_gaps: tuple[int, ...] = (2, 4, 8)
    static_neighbours: int = 3
    iterations: int = 15
    jackknife_blocks: int = 6
