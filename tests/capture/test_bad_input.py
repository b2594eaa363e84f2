"""Every kind of bad input raises InputError naming the file, the frame and what is wrong."""

from __future__ import annotations

import json
import shutil
import struct
import zipfile
from pathlib import Path

import cv2
import lzfse
import numpy as np
import pytest
from conftest import make_capture

from artitwin_core import InputError
from artitwin_core.capture import (
    ReadOptions,
    detect_format,
    read_capture,
    write_nerfstudio,
    write_r3d,
    write_record3d_exr,
    write_stray,
)
from artitwin_core.capture import _lzfse as lzfse_module


def raises(fn, *fragments):
    """Call ``fn`` expecting InputError whose message contains every fragment; returns the message."""
    with pytest.raises(InputError) as info:
        fn()
    msg = str(info.value)
    for frag in fragments:
        assert frag in msg, f"{frag!r} not in {msg!r}"
    return msg


# ---------------------------------------------------------------------------------------- r3d

def rebuild_r3d(src: Path, dst: Path, drop=(), replace=None, add=None, meta=None) -> Path:
    """Copy an .r3d archive, dropping/replacing/adding entries and editing the metadata dict."""
    replace, add = dict(replace or {}), dict(add or {})
    with zipfile.ZipFile(src) as zin, zipfile.ZipFile(dst, "w") as zout:
        for name in zin.namelist():
            if name in drop:
                continue
            data = replace.get(name, zin.read(name))
            if name == "metadata" and meta is not None:
                m = json.loads(data)
                meta(m)
                data = json.dumps(m)
            zout.writestr(name, data)
        for name, data in add.items():
            zout.writestr(name, data)
    return dst


@pytest.fixture
def r3d(tmp_path):
    return write_r3d(make_capture(), tmp_path / "good.r3d")


def test_r3d_missing_frame_entries(r3d, tmp_path):
    bad = rebuild_r3d(r3d, tmp_path / "b.r3d", drop={"rgbd/3.depth"})
    raises(lambda: read_capture(bad), "b.r3d", "frame 3", "rgbd/3.depth is missing")
    bad = rebuild_r3d(r3d, tmp_path / "c.r3d", drop={"rgbd/2.jpg"})
    raises(lambda: read_capture(bad), "c.r3d", "frame 2", "rgbd/2.jpg is missing")
    bad = rebuild_r3d(r3d, tmp_path / "d.r3d", drop={"rgbd/4.conf"})
    raises(lambda: read_capture(bad), "frame 4", "rgbd/4.conf is missing")
    bad = rebuild_r3d(r3d, tmp_path / "e.r3d", drop={"metadata"})
    raises(lambda: read_capture(bad), "e.r3d", "no 'metadata' entry")


def test_r3d_unreadable_frames(r3d, tmp_path):
    bad = rebuild_r3d(r3d, tmp_path / "b.r3d", replace={"rgbd/2.jpg": b"not a jpeg at all"})
    raises(lambda: read_capture(bad), "rgbd/2.jpg", "frame 2", "cannot read the image header")
    small = cv2.imencode(".jpg", np.zeros((10, 10, 3), np.uint8))[1].tobytes()
    bad = rebuild_r3d(r3d, tmp_path / "c.r3d", replace={"rgbd/1.jpg": small})
    raises(lambda: read_capture(bad), "rgbd/1.jpg", "frame 1", "10x10", "64x48")
    bad = rebuild_r3d(r3d, tmp_path / "d.r3d", replace={"rgbd/0.depth": b"bvx2garbage"})
    raises(lambda: read_capture(bad), "rgbd/0.depth", "frame 0")
    not_zip = tmp_path / "nozip.r3d"
    not_zip.write_bytes(b"hello")
    raises(lambda: read_capture(not_zip), "nozip.r3d", "not a readable .r3d")


def test_r3d_more_frames_than_poses(r3d, tmp_path):
    bad = rebuild_r3d(r3d, tmp_path / "b.r3d", meta=lambda m: m.update(poses=m["poses"][:4]))
    raises(lambda: read_capture(bad), "b.r3d", "frame 4", "only 4 poses", "do not match")


def test_r3d_nan_and_non_rigid_poses(r3d, tmp_path):
    def nan_pose(m):
        m["poses"][1][4] = float("nan")

    bad = rebuild_r3d(r3d, tmp_path / "b.r3d", meta=nan_pose)
    raises(lambda: read_capture(bad), "b.r3d!metadata", "frame 1", "NaN")

    def scaled_quaternion(m):
        m["poses"][2][:4] = [2 * q for q in m["poses"][2][:4]]

    bad = rebuild_r3d(r3d, tmp_path / "c.r3d", meta=scaled_quaternion)
    raises(lambda: read_capture(bad), "c.r3d!metadata", "frame 2", "norm 2", "not a rigid rotation")


def test_r3d_empty_depth(tmp_path):
    c = make_capture()
    c.depth[2] = np.nan
    path = write_r3d(c, tmp_path / "e.r3d")
    raises(lambda: read_capture(path), "rgbd/2.depth", "frame 2", "no valid pixel", "allow_empty_depth")
    got = read_capture(path, ReadOptions(allow_empty_depth=True))
    assert np.all(np.isnan(got.depth[2])) and np.isfinite(got.depth[1]).any()


@pytest.mark.parametrize("name,why", [("../evil.txt", "contains '..'"), ("rgbd/../../x", "contains '..'"),
                                      ("/etc/evil", "absolute path"), ("C:/evil", "absolute path"),
                                      ("..\\evil", "contains '..'")])
def test_r3d_entries_escaping_the_target_are_refused(r3d, tmp_path, name, why):
    bad = rebuild_r3d(r3d, tmp_path / "b.r3d", add={name: b"x"})
    raises(lambda: read_capture(bad), "b.r3d", why, "export the recording from Record3D again")


@pytest.mark.parametrize("field,value", [("w", 10**7), ("h", 0), ("dw", -5), ("dh", 2.5), ("w", "64")])
def test_r3d_absurd_sizes_in_metadata(r3d, tmp_path, field, value):
    bad = rebuild_r3d(r3d, tmp_path / "b.r3d", meta=lambda m: m.update({field: value}))
    raises(lambda: read_capture(bad), "b.r3d!metadata", f"field {field!r}")


def test_r3d_bad_intrinsics_metadata(r3d, tmp_path):
    def row_major(m):
        fx, _, _, _, fy, _, cx, cy, _ = m["K"]
        m["K"] = [fx, 0, cx, 0, fy, cy, 0, 0, 1]

    bad = rebuild_r3d(r3d, tmp_path / "b.r3d", meta=row_major)
    raises(lambda: read_capture(bad), "b.r3d!metadata", "not a column-major pinhole matrix")
    bad = rebuild_r3d(r3d, tmp_path / "c.r3d", meta=lambda m: m.update(perFrameIntrinsicCoeffs=m["perFrameIntrinsicCoeffs"][:3]))
    raises(lambda: read_capture(bad), "c.r3d!metadata", "perFrameIntrinsicCoeffs", "3 rows for 6 poses")


def test_r3d_lzfse_payload_larger_than_expected(r3d, tmp_path):
    twice = lzfse.compress(np.ones((48, 32), "<f4").tobytes())  # 2x the 32x24 float32 map
    bad = rebuild_r3d(r3d, tmp_path / "b.r3d", replace={"rgbd/3.depth": twice})
    raises(lambda: read_capture(bad), "rgbd/3.depth", "frame 3", "declares 6144 decompressed bytes, expected 3072")


def test_r3d_lzfse_bomb_is_refused_before_decompressing(r3d, tmp_path, monkeypatch):
    bomb = lzfse.compress(bytes(16 * 2**20))  # 16 MiB of zeros: a few kB compressed
    assert len(bomb) < 2**18
    bad = rebuild_r3d(r3d, tmp_path / "b.r3d", replace={"rgbd/1.depth": bomb})
    real = lzfse.decompress

    def guarded(data):
        if data == bomb:
            raise AssertionError("decompressed a payload that declares the wrong size")
        return real(data)

    monkeypatch.setattr(lzfse_module.lzfse, "decompress", guarded)
    raises(lambda: read_capture(bad), "rgbd/1.depth", "frame 1", f"declares {16 * 2**20} decompressed bytes")


def test_r3d_zip_declaring_a_huge_entry_is_refused_before_reading(r3d, tmp_path):
    data = bytearray(r3d.read_bytes())
    target = b"rgbd/0.depth"
    pos = 0
    while True:  # patch the central directory's uncompressed size of one entry to ~4 GiB
        pos = data.index(b"PK\x01\x02", pos)
        name_len = struct.unpack_from("<H", data, pos + 28)[0]
        if bytes(data[pos + 46 : pos + 46 + name_len]) == target:
            struct.pack_into("<I", data, pos + 24, 0xFFFFFFF0)
            break
        pos += 4
    bad = tmp_path / "huge.r3d"
    bad.write_bytes(bytes(data))
    raises(lambda: read_capture(bad), "huge.r3d!rgbd/0.depth", "frame 0", "would decompress to 4294967280 bytes",
           "max_frame_bytes")


def test_total_size_limit(r3d):
    raises(lambda: read_capture(r3d, ReadOptions(max_total_bytes=20_000)), "max_total_bytes")


def test_r3d_old_file_without_depth_size_timestamps_init_pose(tmp_path):
    c = make_capture(rgb_wh=(48, 64), depth_wh=(192, 256))  # portrait, LiDAR-sized depth

    def strip(m):
        for key in ("dw", "dh", "initPose", "frameTimestamps", "perFrameIntrinsicCoeffs"):
            del m[key]
        m["fps"] = 60

    good = rebuild_r3d(write_r3d(c, tmp_path / "src.r3d"), tmp_path / "old.r3d", meta=strip)
    got = read_capture(good)
    assert got.depth_size == (192, 256)
    np.testing.assert_array_equal(got.depth, c.depth)
    np.testing.assert_allclose(got.timestamps, np.arange(6) / 60)
    np.testing.assert_allclose(got.rgb_intrinsics, np.tile(c.rgb_intrinsics[0], (6, 1)))

    other = make_capture(depth_wh=(32, 24))  # not LiDAR-sized: the assumption must be named
    bad = rebuild_r3d(write_r3d(other, tmp_path / "src2.r3d"), tmp_path / "old2.r3d", meta=strip)
    raises(lambda: read_capture(bad), "frame 0", "no dw/dh; assumed 256x192")


# ---------------------------------------------------------------------------------------- EXR

@pytest.fixture
def exr(tmp_path):
    return write_record3d_exr(make_capture(), tmp_path / "EXR_RGBD")


def test_exr_missing_and_unreadable_frames(exr):
    (exr / "depth" / "3.exr").unlink()
    raises(lambda: read_capture(exr), "3.exr", "frame 3", "depth frame is missing")
    (exr / "depth" / "3.exr").write_bytes(b"garbage")
    raises(lambda: read_capture(exr), "3.exr", "frame 3", "not a readable EXR")


def test_exr_wrong_depth_size_and_missing_colour(exr, tmp_path):
    import OpenEXR

    OpenEXR.File({"compression": OpenEXR.ZIP_COMPRESSION, "type": OpenEXR.scanlineimage},
                 {"R": np.ones((10, 10), np.float16)}).write(str(exr / "depth" / "2.exr"))
    raises(lambda: read_capture(exr), "2.exr", "frame 2", "depth is 10x10 pixels, the recording's first frame 32x24")
    (exr / "rgb" / "1.jpg").unlink()
    raises(lambda: read_capture(exr), "1.jpg", "frame 1", "colour frame is missing")


def test_exr_more_frames_than_poses(exr):
    shutil.copy(exr / "rgb" / "0.jpg", exr / "rgb" / "7.jpg")
    shutil.copy(exr / "depth" / "0.exr", exr / "depth" / "7.exr")
    raises(lambda: read_capture(exr), "7.jpg", "frame 7", "only 6 poses", "do not match")


# ---------------------------------------------------------------------------------- nerfstudio

@pytest.fixture
def ns(tmp_path):
    return write_nerfstudio(make_capture(), tmp_path / "ns")


def edit_json(path: Path, fn) -> None:
    data = json.loads(path.read_text())
    fn(data)
    path.write_text(json.dumps(data))


@pytest.mark.parametrize("model", ["OPENCV_FISHEYE", "EQUIRECTANGULAR", "FISHEYE624", "banana"])
def test_nerfstudio_unknown_camera_model(ns, model):
    edit_json(ns, lambda d: d.update(camera_model=model))
    raises(lambda: read_capture(ns), "transforms.json", "frame 0", f"camera_model {model!r} is not supported")


def test_nerfstudio_non_rigid_and_missing_pose(ns):
    def scale(d):
        d["frames"][3]["transform_matrix"] = (np.array(d["frames"][3]["transform_matrix"]) * 1.5).tolist()

    edit_json(ns, scale)
    raises(lambda: read_capture(ns), "transforms.json", "frame 3", "not a rigid transform")
    edit_json(ns, lambda d: d["frames"][3].pop("transform_matrix"))
    raises(lambda: read_capture(ns), "frame 3", "transform_matrix is missing")


def test_nerfstudio_missing_depth_and_files(ns):
    (ns.parent / "images" / "frame_00004.jpg").unlink()
    raises(lambda: read_capture(ns), "frame_00004.jpg", "frame 4", "missing or unreadable")
    edit_json(ns, lambda d: d["frames"][2].pop("depth_file_path"))
    raises(lambda: read_capture(ns), "transforms.json", "frame 2", "needs depth")


def test_nerfstudio_paths_escaping_the_folder(ns):
    edit_json(ns, lambda d: d["frames"][1].update(file_path="../../etc/passwd"))
    raises(lambda: read_capture(ns), "transforms.json", "frame 1", "points outside the dataset folder")


def test_nerfstudio_depth_png_type_and_empty_depth(ns):
    cv2.imwrite(str(ns.parent / "depth" / "frame_00005.png"), np.ones((24, 32), np.uint8))
    raises(lambda: read_capture(ns), "frame_00005.png", "frame 5", "expected uint16")
    cv2.imwrite(str(ns.parent / "depth" / "frame_00005.png"), np.zeros((24, 32), np.uint16))
    raises(lambda: read_capture(ns), "frame_00005.png", "frame 5", "no valid pixel")


# --------------------------------------------------------------------------------------- Stray

def stray_capture():
    c = make_capture()
    k = np.tile(c.rgb_intrinsics[:1], (6, 1))
    from artitwin_core.capture import depth_intrinsics_from_rgb

    return c.__class__(**{**c.__dict__, "rgb_intrinsics": k,
                          "depth_intrinsics": depth_intrinsics_from_rgb(k, c.rgb_size, c.depth_size)})


@pytest.fixture
def stray(tmp_path):
    return write_stray(stray_capture(), tmp_path / "stray", lossless=True)


def test_stray_missing_depth_and_short_video(stray):
    (stray / "depth" / "000004.png").unlink()
    raises(lambda: read_capture(stray), "000004.png", "frame 4", "depth frame is missing")
    shutil.copy(stray / "depth" / "000000.png", stray / "depth" / "000004.png")
    shutil.copy(stray / "depth" / "000000.png", stray / "depth" / "000006.png")
    shutil.copy(stray / "confidence" / "000000.png", stray / "confidence" / "000006.png")
    with (stray / "odometry.csv").open("a") as fh:
        fh.write("0.5, 6, 0, 0, 0, 0, 0, 0, 1\n")
    raises(lambda: read_capture(stray), "rgb.mp4", "frame 6", "video ends before frame 6", "do not match")


def test_stray_bad_odometry(stray):
    text = (stray / "odometry.csv").read_text().splitlines()
    (stray / "odometry.csv").write_text("\n".join([text[0], *text[1:3], text[3] + ", 9"]))
    raises(lambda: read_capture(stray), "odometry.csv", "row 3 has 10 values")
    parts = text[3].split(", ")
    parts[-1] = "nan"
    (stray / "odometry.csv").write_text("\n".join([*text[:3], ", ".join(parts), *text[4:]]) + "\n")
    raises(lambda: read_capture(stray), "odometry.csv", "frame 2", "not rigid")
    (stray / "odometry.csv").write_text("a, b, c\n1, 2, 3\n")
    raises(lambda: read_capture(stray), "odometry.csv", "lacks the columns")
    (stray / "camera_matrix.csv").write_text("50,0,640\n0,50,480\n0,0,1\n")  # K at 1280x960, video 64x48
    (stray / "odometry.csv").write_text("\n".join(text) + "\n")
    raises(lambda: read_capture(stray), "camera_matrix.csv", "principal point (640.0, 480.0) lies outside the 64x48")
    (stray / "camera_matrix.csv").write_text("1,2\n3,4\n")
    raises(lambda: read_capture(stray), "camera_matrix.csv", "3 rows of 3 numbers")


def test_stray_old_variant_npy_depth_and_bare_odometry(stray):
    c = stray_capture()
    for p in (stray / "depth").glob("*.png"):
        mm = cv2.imread(str(p), cv2.IMREAD_UNCHANGED)
        np.save(p.with_suffix(".npy"), mm)
        p.unlink()
    rows = (stray / "odometry.csv").read_text().splitlines()[1:]
    (stray / "odometry.csv").write_text("x, y, z, qx, qy, qz, qw\n" + "\n".join(
        ", ".join(r.split(", ")[2:]) for r in rows) + "\n")
    got = read_capture(stray)
    np.testing.assert_array_equal(got.frame_ids, np.arange(6))
    np.testing.assert_allclose(got.world_from_camera, c.world_from_camera, atol=1e-9)
    ok = np.isfinite(c.depth)
    assert np.max(np.abs(got.depth[ok] - c.depth[ok])) <= 0.0005 + 1e-6  # mm quantisation
    np.testing.assert_allclose(got.timestamps, np.arange(6) / 30.0, atol=1e-6)  # video fps (30)


def test_stray_npy_depth_of_the_wrong_shape(stray):
    (stray / "depth" / "000001.png").unlink()
    np.save(stray / "depth" / "000001.npy", np.ones((5, 5), np.uint16))
    raises(lambda: read_capture(stray), "000001.npy", "frame 1", "depth is 5x5, expected 32x24")


# ------------------------------------------------------------------------------- detection etc.

def test_detect_format_says_what_it_looked_for(tmp_path):
    (tmp_path / "notes.txt").write_text("hi")
    msg = raises(lambda: detect_format(tmp_path), str(tmp_path), "notes.txt")
    for looked_for in (".r3d", "metadata.json", "transforms.json", "rgb.mp4", "odometry.csv"):
        assert looked_for in msg
    raises(lambda: detect_format(tmp_path / "notes.txt"), "not a recording", "transforms.json")
    raises(lambda: detect_format(tmp_path / "nope"), "no such file or folder")


def test_read_options_are_validated():
    raises(lambda: ReadOptions(stride=0), "stride")
    raises(lambda: ReadOptions(max_frames=0), "max_frames")
    raises(lambda: ReadOptions(rgb_max_width=2), "rgb_max_width")
