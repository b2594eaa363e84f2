"""The USD stage: valid, one fixed-base articulation, joints read back exactly, splats under their links.

The hand-made boxes of ``test_simulators`` (tilted axes, off-origin pivots) so a wrong frame, sign
or axis convention shows as centimetres. The round trip drives every part through q(t) and both
limits, reads the joints back from the stage and compares every mesh vertex with
``joint_transforms``; Newton's USD importer does the same where Newton is installed.
"""

from __future__ import annotations

from dataclasses import replace

import numpy as np
import pytest
import trimesh
from pxr import Gf, Sdf, Usd, UsdGeom, UsdPhysics, UsdVol

from artitwin_core import InputError
from artitwin_core.export import (
    Z_UP_FROM_Y_UP,
    SimPart,
    check_usd,
    export_usd,
    mesh_inertial,
    parse_physics,
    read_usd_joints,
    validate_usd,
)
from artitwin_core.gaussians import GaussianParams
from artitwin_core.geometry import quat_wxyz_to_matrix
from tests.export.test_simulators import BASE, DENSITY, PARTS, _box, _joint

# The bound on a part's pose read back from the stage. Joint frames are float32 in USD
# (localPos/localRot): measured 5e-8 m at these 1 m scenes (pxr) and 2e-7 m in Newton (float32 FK).
TOL_M = 1e-6
ALL = {**PARTS, "shelf": (_joint("fixed", [1.0, 0, 0], [0.0, 0.5, -0.2], [0.0, 0.0]),
                          _box([-0.3, 0.48, -0.4], [0.3, 0.52, 0.0]))}
SCENES = {"revolute": ["door"], "prismatic": ["drawer"], "two_parts": ["door", "drawer"],
          "screw_and_fixed": ["knob", "shelf"]}


def _gaussians(names: list[str], n: int = 300, seed: int = 0) -> GaussianParams:
    """Random Gaussians, labels 0 (background), 1 (interior) and 2 + k for each part k."""
    rng = np.random.default_rng(seed)
    return GaussianParams(
        means=rng.normal(0, 0.5, (n, 3)).astype(np.float32), quats_wxyz=rng.normal(size=(n, 4)).astype(np.float32),
        log_scales=rng.normal(-4, 0.5, (n, 3)).astype(np.float32), opacity_logits=rng.normal(size=n).astype(np.float32),
        sh=rng.normal(0, 0.3, (n, 16, 3)).astype(np.float32),
        labels=rng.integers(0, 2 + len(names), n).astype(np.int32),
    )


def _export(tmp_path, names, **kwargs):
    parts = [(n, ALL[n][0], ALL[n][1], [ALL[n][1]]) for n in names]
    kwargs.setdefault("gaussians", _gaussians(names))
    return export_usd(tmp_path, BASE, parts, base_collision=[BASE], density_kg_m3=DENSITY, **kwargs)


def _sim_parts(names, joint_of=lambda n, j: j, n: int = 9) -> list[SimPart]:
    out = []
    for name in names:
        j, mesh = ALL[name]
        q = np.zeros(n) if j.joint_type == "fixed" else np.linspace(*j.q_range, n)
        out.append(SimPart(name, replace(joint_of(name, j), q=q), np.asarray(mesh.vertices) - j.pivot))
    return out


@pytest.mark.parametrize("scene", list(SCENES))
def test_round_trip_reads_back_every_joint_and_moves_the_parts_where_the_twin_does(tmp_path, scene):
    names = SCENES[scene]
    result = _export(tmp_path, names)
    (usd,) = check_usd(result.path, _sim_parts(names), simulators=("usd",))
    print(scene, usd.status, f"{usd.max_error_m:.2e} m", usd.note)
    assert usd.status == "ok", usd
    assert set(usd.part_errors_m) == set(names)
    assert usd.states == sum(1 if ALL[n][0].joint_type == "fixed" else 11 for n in names)
    assert usd.max_error_m < TOL_M


def test_newton_loads_the_articulation_and_agrees(tmp_path):
    pytest.importorskip("newton", reason="Newton not installed (pip install newton newton-usd-schemas)")
    names = ["door", "drawer", "knob", "shelf"]
    result = _export(tmp_path, names)
    (newton,) = check_usd(result.path, _sim_parts(names), simulators=("newton_usd",))
    print(newton.status, f"{newton.max_error_m:.2e} m", newton.note)
    # ok includes: limits back in radians equal q_range, and the knob's slide coupled to its turn.
    assert newton.status == "ok", newton
    assert newton.max_error_m < TOL_M


def test_stage_states_units_axes_and_one_fixed_base_articulation(tmp_path):
    result = _export(tmp_path, ["door", "drawer", "knob"])
    stage = Usd.Stage.Open(str(result.path))
    assert UsdGeom.GetStageUpAxis(stage) == UsdGeom.Tokens.z
    assert UsdGeom.GetStageMetersPerUnit(stage) == 1.0 and UsdPhysics.GetStageKilogramsPerUnit(stage) == 1.0
    root = stage.GetDefaultPrim()
    assert root.GetPath() == Sdf.Path("/artitwin")
    # The one axis change: canonical +y (up) is the stage's +z.
    m = np.asarray(UsdGeom.Xformable(root).GetLocalTransformation(), np.float64).T
    np.testing.assert_allclose(m, Z_UP_FROM_Y_UP, atol=1e-12)
    assert validate_usd(stage) == []
    parsed = parse_physics(stage)
    (art,) = parsed[UsdPhysics.ObjectType.Articulation][1]
    assert [str(p) for p in art.rootPrims] == ["/artitwin/base"]
    assert root.GetChild("base").HasAPI(UsdPhysics.ArticulationRootAPI)
    assert Sdf.Path.emptyPath in art.articulatedBodies  # the world: a fixed base
    assert len(art.articulatedJoints) == 5  # root, door, drawer, knob slide + turn
    for name in ("door", "drawer", "knob"):
        for piece in root.GetChild(name).GetChild("collision").GetChildren():
            assert piece.HasAPI(UsdPhysics.CollisionAPI)
            assert UsdPhysics.MeshCollisionAPI(piece).GetApproximationAttr().Get() == UsdPhysics.Tokens.convexHull
            assert UsdGeom.Imageable(piece).GetPurposeAttr().Get() == UsdGeom.Tokens.guide
    scene = UsdPhysics.Scene(stage.GetPrimAtPath("/physicsScene"))
    assert tuple(scene.GetGravityDirectionAttr().Get()) == (0.0, 0.0, -1.0)


def test_joints_limits_and_masses_are_what_the_twin_says(tmp_path):
    result = _export(tmp_path, ["door", "drawer", "knob"])
    stage = Usd.Stage.Open(str(result.path))
    joints = {j.name: j for j in read_usd_joints(stage)}
    assert set(joints) == {"root_joint", "door_joint", "drawer_joint", "knob_slide", "knob_joint"}
    door = UsdPhysics.RevoluteJoint(stage.GetPrimAtPath("/artitwin/joints/door_joint"))
    # Degrees in the file, as USD wants.
    assert door.GetUpperLimitAttr().Get() == pytest.approx(np.degrees(1.3), rel=1e-6)
    for name, parent in [("door", "base"), ("drawer", "base"), ("knob", "knob_slider")]:
        j, twin = joints[f"{name}_joint"], ALL[name][0]
        assert (j.kind, j.parent, j.child, j.axis) == (
            "revolute" if twin.joint_type == "screw" else twin.joint_type, parent, name, "X")
        np.testing.assert_allclose([j.lower, j.upper], twin.q_range, atol=1e-6)
        # The joint frame's X is the twin's axis, in both link frames (canonical axes).
        np.testing.assert_allclose(j.parent_from_joint[:3, 0], twin.axis, atol=1e-6)
        np.testing.assert_allclose(j.child_from_joint[:3, 0], twin.axis, atol=1e-6)
        mass = UsdPhysics.MassAPI(stage.GetPrimAtPath(f"/artitwin/{name}"))
        want = mesh_inertial(ALL[name][1], DENSITY, pieces=[ALL[name][1]])
        assert mass.GetMassAttr().Get() == pytest.approx(want.mass_kg, rel=1e-6)
        np.testing.assert_allclose(mass.GetCenterOfMassAttr().Get(), want.com - twin.pivot, atol=1e-6)
        rot = quat_wxyz_to_matrix(np.array([mass.GetPrincipalAxesAttr().Get().GetReal(),
                                            *mass.GetPrincipalAxesAttr().Get().GetImaginary()]))
        inertia = rot @ np.diag(mass.GetDiagonalInertiaAttr().Get()) @ rot.T
        np.testing.assert_allclose(inertia, want.inertia, atol=1e-6 * np.abs(want.inertia).max())
    slide = joints["knob_slide"]
    assert (slide.kind, slide.parent, slide.child) == ("prismatic", "base", "knob_slider")
    np.testing.assert_allclose([slide.lower, slide.upper], [0.0, 0.004 * 3.0], atol=1e-7)
    prim = stage.GetPrimAtPath("/artitwin/joints/knob_slide")
    # A PhysX schema usd-core does not know: authored by name, so only the list op shows it.
    assert "PhysxMimicJointAPI:transX" in prim.GetMetadata("apiSchemas").GetAddedOrExplicitItems()
    assert prim.GetAttribute("physxMimicJoint:transX:gearing").Get() == pytest.approx(-0.004)


@pytest.mark.parametrize("payload_min_bytes", [None, 0])
def test_splats_sit_under_their_links_in_the_3dgs_schema(tmp_path, payload_min_bytes):
    names = ["door", "drawer"]
    g = _gaussians(names)
    result = _export(tmp_path, names, gaussians=g, payload_min_bytes=payload_min_bytes)
    assert bool(result.payloads) == (payload_min_bytes == 0)
    for path in result.payloads.values():
        assert path.suffix == ".usdc" and path.is_file()
    stage = Usd.Stage.Open(str(result.path))
    assert validate_usd(stage) == []
    labels = np.asarray(g.labels)
    for link, keep, pivot in [("base", labels < 2, np.zeros(3)),
                              *[(n, labels == 2 + k, ALL[n][0].pivot) for k, n in enumerate(names)]]:
        assert result.splat_counts[link] == keep.sum()
        sub = "looks/splats" if payload_min_bytes == 0 else "splats"
        prim = stage.GetPrimAtPath(f"/artitwin/{link}/{sub}")
        assert prim.IsA(UsdVol.ParticleField3DGaussianSplat), link
        pos = np.asarray(UsdVol.ParticleFieldPositionAttributeAPI(prim).GetPositionsAttr().Get())
        np.testing.assert_allclose(pos + pivot, g.means[keep], atol=1e-6)  # float32 in link frames
        quats = UsdVol.ParticleFieldOrientationAttributeAPI(prim).GetOrientationsAttr().Get()
        wxyz = np.array([[q.GetReal(), *q.GetImaginary()] for q in quats])
        want = g.quats_wxyz[keep] / np.linalg.norm(g.quats_wxyz[keep], axis=1, keepdims=True)
        np.testing.assert_allclose(wxyz, want, atol=1e-6)  # the real part is w: no xyzw mix-up
        scales = np.asarray(UsdVol.ParticleFieldScaleAttributeAPI(prim).GetScalesAttr().Get())
        np.testing.assert_allclose(scales, np.exp(g.log_scales[keep]), rtol=1e-6)
        opac = np.asarray(UsdVol.ParticleFieldOpacityAttributeAPI(prim).GetOpacitiesAttr().Get())
        np.testing.assert_allclose(opac, 1 / (1 + np.exp(-g.opacity_logits[keep])), atol=1e-6)
        sh = UsdVol.ParticleFieldSphericalHarmonicsAttributeAPI(prim)
        assert sh.GetRadianceSphericalHarmonicsDegreeAttr().Get() == 3
        coeffs = np.asarray(sh.GetRadianceSphericalHarmonicsCoefficientsAttr().Get())
        np.testing.assert_array_equal(coeffs.reshape(-1, 16, 3), g.sh[keep])  # particle-major, DC first


def test_a_y_up_stage_when_asked(tmp_path):
    result = _export(tmp_path, ["door"], sim_from_canonical=None)
    stage = Usd.Stage.Open(str(result.path))
    assert UsdGeom.GetStageUpAxis(stage) == UsdGeom.Tokens.y
    (usd,) = check_usd(result.path, _sim_parts(["door"]), sim_from_canonical=None, simulators=("usd",))
    assert usd.status == "ok" and usd.max_error_m < TOL_M, usd
    with pytest.raises(InputError, match="y-up or z-up"):
        _export(tmp_path, ["door"], sim_from_canonical=np.diag([1.0, -1.0, -1.0, 1.0]))


def test_a_wrong_pivot_is_a_mismatch(tmp_path):
    """Negative control: the twin's door pivot 1 cm off the exported one."""
    result = _export(tmp_path, ["door", "drawer"])

    def shifted(name, j):
        return replace(j, pivot=j.pivot + np.array([0.01, 0, 0])) if name == "door" else j

    parts = [replace(sp, points=np.asarray(ALL[sp.link][1].vertices) - ALL[sp.link][0].pivot)
             for sp in _sim_parts(["door", "drawer"], shifted)]
    (usd,) = check_usd(result.path, parts, simulators=("usd",))
    assert usd.status == "mismatch"
    assert 9.9e-3 < usd.part_errors_m["door"] < 3e-2 and usd.part_errors_m["drawer"] < TOL_M


def test_a_tampered_stage_fails_the_check_with_reasons(tmp_path):
    result = _export(tmp_path, ["door", "drawer"])
    stage = Usd.Stage.Open(str(result.path))
    UsdPhysics.RevoluteJoint(stage.GetPrimAtPath("/artitwin/joints/door_joint")).GetUpperLimitAttr().Set(45.0)
    drawer = stage.GetPrimAtPath("/artitwin/drawer")
    drawer.GetAttribute("xformOp:translate").Set(Gf.Vec3d(0, 0.3, 0.5))  # not where its joint puts it
    stage.RemovePrim("/artitwin/joints/root_joint")
    stage.GetRootLayer().Save()
    (usd,) = check_usd(result.path, _sim_parts(["door", "drawer"]), simulators=("usd",))
    assert usd.status == "failed"
    for words in ("door_joint: limits", "drawer: authored pose", "not fixed to the world"):
        assert words in usd.note, (words, usd.note)


def test_a_joint_with_no_range_is_an_input_error(tmp_path):
    door = replace(ALL["door"][0], q_range=np.array([np.nan, np.nan]))
    with pytest.raises(InputError, match="q_range"):
        export_usd(tmp_path, BASE, [("door", door, ALL["door"][1], [ALL["door"][1]])], base_collision=[BASE])
    assert not (tmp_path / "artitwin.usda").exists()  # refused before anything was written


def test_degenerate_meshes_are_refused_or_cleaned(tmp_path):
    joint, box = ALL["door"]
    line = trimesh.Trimesh(np.array([[0.0, 0, 0], [0.5, 0, 0], [1.0, 0, 0]]), np.array([[0, 1, 2]]), process=False)
    with pytest.raises(InputError, match="degenerate"):
        export_usd(tmp_path, BASE, [("door", joint, line, [box])], base_collision=[BASE])
    # A box with one non-finite vertex and a flat collision piece: the bad faces go, the piece is
    # replaced by the box's bounding box, and both fallbacks are reported.
    verts = np.vstack([box.vertices, [[np.nan, 0.0, 0.0]]])
    faces = np.vstack([box.faces, [[0, 1, len(box.vertices)]]])
    dirty = trimesh.Trimesh(verts, faces, process=False)
    flat = trimesh.Trimesh(np.array([[0.0, 0, 0], [1, 0, 0], [0, 1, 0], [1, 1, 0]]), np.array([[0, 1, 2], [1, 3, 2]]),
                           process=False)
    result = export_usd(tmp_path, BASE, [("door", joint, dirty, [flat])], base_collision=[BASE])
    assert any("1 of 13 visual faces" in n for n in result.notes), result.notes
    assert any("bounding box" in n for n in result.notes), result.notes
    stage = Usd.Stage.Open(str(result.path))
    assert validate_usd(stage) == []
    points = np.asarray(UsdGeom.Mesh(stage.GetPrimAtPath("/artitwin/door/visual")).GetPointsAttr().Get())
    assert np.isfinite(points).all() and len(points) == 8
    (piece,) = stage.GetPrimAtPath("/artitwin/door/collision").GetChildren()
    assert len(UsdGeom.Mesh(piece).GetPointsAttr().Get()) == 8  # the box


def test_gaussians_of_an_unknown_part_are_an_input_error(tmp_path):
    with pytest.raises(InputError, match="labelled for part 2"):
        _export(tmp_path, ["door", "drawer"], gaussians=_gaussians(["a", "b", "c"], seed=1))


def test_a_part_called_joints_does_not_collide_with_the_joints_scope(tmp_path):
    joint, mesh = ALL["door"]
    result = export_usd(tmp_path, BASE, [("joints", joint, mesh, [mesh])], base_collision=[BASE])
    part = SimPart("joints_2", replace(joint, q=np.linspace(*joint.q_range, 5)), np.asarray(mesh.vertices) - joint.pivot)
    (usd,) = check_usd(result.path, [part], simulators=("usd",))
    assert usd.status == "ok" and usd.max_error_m < TOL_M, usd
