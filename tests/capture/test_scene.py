"""Finding a scene's static and dynamic recordings, and hashing inputs: recording_files."""

from __future__ import annotations

import json

import pytest
from conftest import make_capture

from artitwin_core import InputError
from artitwin_core.capture import (
    SceneRecordings,
    find_scene_recordings,
    read_capture,
    recording_files,
    write_r3d,
    write_record3d_exr,
)


def test_r3d_files_layout(tmp_path):
    (tmp_path / "static.r3d").write_bytes(b"")
    (tmp_path / "dynamic.r3d").write_bytes(b"")
    (tmp_path / "notes.txt").write_text("")
    assert find_scene_recordings(tmp_path) == SceneRecordings(tmp_path / "static.r3d", tmp_path / "dynamic.r3d")


def test_folder_layout(tmp_path):
    (tmp_path / "static").mkdir()
    (tmp_path / "dynamic.exr").mkdir()
    got = find_scene_recordings(tmp_path)
    assert got.static == tmp_path / "static" and got.dynamic == tmp_path / "dynamic.exr"


def test_manifest_overrides_names(tmp_path):
    (tmp_path / "static.r3d").write_bytes(b"")
    (tmp_path / "dynamic.r3d").write_bytes(b"")
    (tmp_path / "takes").mkdir()
    (tmp_path / "takes" / "a.r3d").write_bytes(b"")
    (tmp_path / "takes" / "b").mkdir()
    (tmp_path / "scene.json").write_text(json.dumps({"static": "takes/b", "dynamic": "takes/a.r3d"}))
    got = find_scene_recordings(tmp_path)
    assert got.static == (tmp_path / "takes" / "b").resolve()
    assert got.dynamic == (tmp_path / "takes" / "a.r3d").resolve()


def test_layout_errors(tmp_path):
    with pytest.raises(InputError, match="scene folder does not exist"):
        find_scene_recordings(tmp_path / "nope")
    (tmp_path / "static.r3d").write_bytes(b"")
    with pytest.raises(InputError, match=r"no dynamic recording found.*static\.r3d.*scene\.json"):
        find_scene_recordings(tmp_path)
    (tmp_path / "dynamic.r3d").write_bytes(b"")
    (tmp_path / "dynamic").mkdir()
    with pytest.raises(InputError, match=r"several candidates for the dynamic recording.*scene\.json"):
        find_scene_recordings(tmp_path)


def test_manifest_errors(tmp_path):
    m = tmp_path / "scene.json"
    m.write_text("{not json")
    with pytest.raises(InputError, match="scene.json: cannot read the scene manifest"):
        find_scene_recordings(tmp_path)
    m.write_text(json.dumps({"static": "a.r3d"}))
    with pytest.raises(InputError, match="field 'dynamic' is missing"):
        find_scene_recordings(tmp_path)
    m.write_text(json.dumps({"static": "a.r3d", "dynamic": "b.r3d"}))
    with pytest.raises(InputError, match="static recording 'a.r3d' does not exist"):
        find_scene_recordings(tmp_path)
    (tmp_path / "a.r3d").write_bytes(b"")
    m.write_text(json.dumps({"static": "a.r3d", "dynamic": "./a.r3d"}))
    with pytest.raises(InputError, match="name the same recording"):
        find_scene_recordings(tmp_path)


def test_a_scene_reads_end_to_end(tmp_path):
    write_r3d(make_capture(seed=1), tmp_path / "static.r3d")
    write_record3d_exr(make_capture(seed=2), tmp_path / "dynamic")
    rec = find_scene_recordings(tmp_path)
    assert read_capture(rec.static).source_format == "record3d-r3d"
    assert read_capture(rec.dynamic).source_format == "record3d-exr"


def test_recording_files_lists_what_the_reader_uses(tmp_path):
    root = write_record3d_exr(make_capture(frame_ids=[0, 2, 3, 5, 6, 9]), tmp_path / "rec")
    (root / "thumbnail.png").write_bytes(b"not part of the recording")
    files = recording_files(root)
    names = [f.relative_to(root).as_posix() for f in files]
    assert names == sorted(["metadata.json"] + [f"rgb/{i}.jpg" for i in (0, 2, 3, 5, 6, 9)]
                           + [f"depth/{i}.exr" for i in (0, 2, 3, 5, 6, 9)])
    assert recording_files(root) == files  # deterministic order
