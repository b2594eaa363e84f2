"""The 3DGS .ply writer and reader: exact round trip, INRIA property layout."""

from __future__ import annotations

import numpy as np
import pytest

from artitwin_core import InputError
from artitwin_core.gaussians import GaussianParams
from artitwin_core.reconstruction import read_ply, write_ply


def _random_params(n: int, degree: int, seed: int = 0) -> GaussianParams:
    rng = np.random.default_rng(seed)
    k = (degree + 1) ** 2
    return GaussianParams(
        means=rng.normal(size=(n, 3)).astype(np.float32),
        quats_wxyz=rng.normal(size=(n, 4)).astype(np.float32),
        log_scales=rng.normal(-4, 1, size=(n, 3)).astype(np.float32),
        opacity_logits=rng.normal(size=n).astype(np.float32),
        sh=rng.normal(size=(n, k, 3)).astype(np.float32),
        labels=np.zeros(n, np.int32),
    )


@pytest.mark.parametrize("degree", [0, 1, 3])
def test_round_trip_is_exact(tmp_path, degree):
    p = _random_params(257, degree)
    q = read_ply(write_ply(tmp_path / "m.ply", p))
    for name in ("means", "quats_wxyz", "log_scales", "opacity_logits", "sh"):
        np.testing.assert_array_equal(getattr(q, name), getattr(p, name))
    assert q.sh_degree == degree


def test_inria_layout(tmp_path):
    p = _random_params(3, 3)
    path = write_ply(tmp_path / "m.ply", p)
    raw = path.read_bytes()
    head, body = raw.split(b"end_header\n", 1)
    props = [line.split()[-1] for line in head.decode().splitlines() if line.startswith("property float")]
    assert props[:9] == ["x", "y", "z", "nx", "ny", "nz", "f_dc_0", "f_dc_1", "f_dc_2"]
    assert props[9:54] == [f"f_rest_{i}" for i in range(45)]
    assert props[54:] == ["opacity", "scale_0", "scale_1", "scale_2", "rot_0", "rot_1", "rot_2", "rot_3"]
    assert b"format binary_little_endian 1.0" in head
    data = np.frombuffer(body, "<f4").reshape(3, 62)
    # Channel-major f_rest: all 15 red coefficients, then green, then blue (INRIA's construct_list_of_attributes).
    np.testing.assert_array_equal(data[:, 9:24], p.sh[:, 1:, 0])
    np.testing.assert_array_equal(data[:, 24:39], p.sh[:, 1:, 1])
    np.testing.assert_array_equal(data[:, 39:54], p.sh[:, 1:, 2])
    np.testing.assert_array_equal(data[:, 54], p.opacity_logits)
    np.testing.assert_array_equal(data[:, 58:62], p.quats_wxyz)


def test_rejects_non_3dgs_files(tmp_path):
    bad = tmp_path / "bad.ply"
    bad.write_bytes(b"ply\nformat ascii 1.0\nelement vertex 0\nend_header\n")
    with pytest.raises(InputError, match="binary little-endian"):
        read_ply(bad)
    trunc = tmp_path / "trunc.ply"
    write_ply(trunc, _random_params(4, 0))
    trunc.write_bytes(trunc.read_bytes()[:-10])
    with pytest.raises(InputError, match="truncated"):
        read_ply(trunc)
