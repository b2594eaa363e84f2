"""Property tests: pose conversions through each format's pose encoding, and the LZFSE size scan."""

from __future__ import annotations

import lzfse
import numpy as np
from hypothesis import given, settings
from hypothesis import strategies as st

from artitwin_core.capture import Capture
from artitwin_core.capture._lzfse import declared_raw_size
from artitwin_core.capture._record3d_meta import build_metadata, parse_metadata
from artitwin_core.geometry import axis_angle_to_matrix, make_se3

unit = st.floats(-1, 1, allow_nan=False)
angles = st.floats(0, np.pi, allow_nan=False)  # includes 180 degree turns (quaternion w = 0)


def capture_with_pose(pose: np.ndarray) -> Capture:
    return Capture(
        rgb=np.zeros((1, 4, 4, 3), np.uint8), depth=np.ones((1, 2, 2), np.float32), confidence=None,
        rgb_intrinsics=np.array([[3.0, 3.0, 1.5, 1.5]]), depth_intrinsics=np.array([[1.5, 1.5, 0.75, 0.75]]),
        world_from_camera=pose[None], timestamps=np.zeros(1), frame_ids=np.zeros(1, np.int64),
    )


@settings(max_examples=200, deadline=None)
@given(ax=st.tuples(unit, unit, unit).filter(lambda a: np.linalg.norm(a) > 1e-3), angle=angles,
       trans=st.tuples(st.floats(-50, 50), st.floats(-50, 50), st.floats(-50, 50)))
def test_record3d_pose_encoding_round_trips(ax, angle, trans):
    pose = make_se3(axis_angle_to_matrix(np.array(ax), angle), np.array(trans))
    meta = parse_metadata(build_metadata(capture_with_pose(pose)), "meta")
    # Float64 JSON keeps full precision; the bound is the quaternion <-> matrix round off.
    np.testing.assert_allclose(meta.world_from_camera(0, "meta"), pose, atol=1e-12)


@settings(max_examples=60, deadline=None)
@given(data=st.binary(max_size=20000), repeat=st.integers(1, 60))
def test_lzfse_declared_size_matches_the_data(data, repeat):
    raw = data * repeat  # repeats make LZFSE and LZVN blocks, short inputs raw blocks
    assert declared_raw_size(lzfse.compress(raw)) == len(raw)
