"""Hostile part names cannot escape the output folder or break the XML."""

from __future__ import annotations

import re
import xml.etree.ElementTree as ET

import numpy as np
import trimesh

from artitwin_core.export import export_mjcf, export_urdf, sanitize_name
from artitwin_core.joints import Joint

SAFE = re.compile(r"^[A-Za-z_][A-Za-z0-9_]*$")
HOSTILE = ["../door 1", "tür", "门", "a/b\\c", "..", "", "door 1", "Door_1", "1st drawer", "<x>&\"'", "/etc/passwd"]


def test_sanitize_name_examples():
    assert sanitize_name("../door 1") == "door_1"
    assert sanitize_name("tür") == "tur"
    assert sanitize_name("门") == "part"  # nothing ASCII survives: the fallback
    assert sanitize_name("1st drawer") == "p_1st_drawer"
    for name in HOSTILE:
        assert SAFE.match(sanitize_name(name)), name


def test_export_with_hostile_names_stays_inside_and_unique(tmp_path):
    box = trimesh.creation.box(extents=[0.2, 0.2, 0.2])
    z = np.zeros(3)
    joint = Joint("prismatic", np.array([0.0, 0, 1]), z, z, np.array([0.0, 0.1]), z, z)
    parts = [(name, joint, box, [box]) for name in HOSTILE]
    out = tmp_path / "out"
    urdf = export_urdf(out, box, parts, name="../../evil robot", base_collision=[box])
    mjcf = export_mjcf(out, box, parts, name="../../evil robot", base_collision=[box])
    assert urdf.parent == out and mjcf.parent == out
    # Every file lies under out/ (nothing written beside it) with a safe name.
    assert sorted(p.name for p in tmp_path.iterdir()) == ["out"]
    for path in out.rglob("*"):
        if path.is_file():
            assert SAFE.match(path.stem), path
            assert path.resolve().is_relative_to(out.resolve())
    links = [el.get("name") for el in ET.parse(urdf).getroot().iter("link")]
    assert len(links) == len(set(n.lower() for n in links)) == len(HOSTILE) + 2  # + world, base
    assert all(SAFE.match(n) for n in links)
    for el in ET.parse(urdf).getroot().iter("mesh"):
        rel = el.get("filename")
        assert not rel.startswith("/") and ".." not in rel.split("/")
        assert (out / rel).is_file()


def test_screw_helper_link_never_takes_a_part_name(tmp_path):
    box = trimesh.creation.box(extents=[0.2, 0.2, 0.2])
    z = np.zeros(3)
    screw = Joint("screw", np.array([0.0, 0, 1]), z, z, np.array([0.0, 2.0]), z, z, pitch=0.01)
    hinge = Joint("revolute", np.array([0.0, 1, 0]), z, z, np.array([0.0, 1.0]), z, z)
    urdf = export_urdf(tmp_path, box, [("knob", screw, box, [box]), ("knob_slider", hinge, box, [box])],
                       base_collision=[box])
    root = ET.parse(urdf).getroot()
    links = [el.get("name") for el in root.iter("link")]
    assert len(links) == len(set(links)) == 5  # world, base, knob, knob_slider, the helper
    parents = {j.find("child").get("link"): j.find("parent").get("link") for j in root.iter("joint")}
    assert parents["knob_slider"] == "base"  # the user's part stays a child of the base
    assert parents["knob"] not in ("base", "knob_slider")  # the screw hangs from its own helper
