"""check_in_simulators: exact on correct files, loud on wrong ones, graceful without a simulator."""

from __future__ import annotations

from dataclasses import replace

import numpy as np
import pytest

from artitwin_core.export import SIMULATORS, SimPart, _simcheck, check_in_simulators, export_mjcf, export_urdf
from tests.export.test_simulators import BASE, PARTS, _box, _joint

pytest.importorskip("yourdfpy", reason="yourdfpy not installed")
pytest.importorskip("pybullet", reason="pybullet not installed")
pytest.importorskip("mujoco", reason="mujoco not installed")

# A fixed part too: MuJoCo's URDF importer would fuse its body into the base unless told not to.
ALL_PARTS = {**PARTS, "shelf": (_joint("fixed", [1.0, 0, 0], [0.0, 0.5, -0.2], [0.0, 0.0]),
                                 _box([-0.3, 0.48, -0.4], [0.3, 0.52, 0.0]))}


def _with_q(joint, n: int = 9):
    lo, hi = joint.q_range
    return replace(joint, q=np.linspace(lo, hi, n) if joint.joint_type != "fixed" else np.zeros(n))


@pytest.fixture(scope="module")
def files(tmp_path_factory):
    out = tmp_path_factory.mktemp("simcheck")
    parts = [(name, j, m, [m]) for name, (j, m) in ALL_PARTS.items()]
    return export_urdf(out, BASE, parts, base_collision=[BASE]), export_mjcf(out, BASE, parts, base_collision=[BASE])


def _sim_parts(joint_of=lambda name, j: j) -> list[SimPart]:
    return [SimPart(name, _with_q(joint_of(name, j)), np.asarray(m.vertices) - j.pivot)
            for name, (j, m) in ALL_PARTS.items()]


def test_correct_files_match_in_every_simulator(files):
    results = check_in_simulators(*files, _sim_parts())
    assert [r.simulator for r in results] == list(SIMULATORS)
    for r in results:
        print(r.simulator, r.status, f"{r.max_error_m:.2e} m", r.note)
        assert r.status == "ok", r
        assert set(r.part_errors_m) == set(ALL_PARTS)
        # 9 states + 2 limits per moving part, 1 for the fixed one.
        assert r.states == 3 * 11 + 1
        assert r.max_error_m < 1e-6  # exact frames: measured <= 3e-8 m (PyBullet), see test_simulators


def test_a_wrong_pivot_is_reported_as_a_mismatch(files):
    """Negative control: the twin's door pivot 1 cm off the exported one must show as > 5 mm."""
    def shifted(name, j):
        return replace(j, pivot=j.pivot + np.array([0.01, 0.0, 0.0])) if name == "door" else j

    # Points stay those of the exported link frame; only the twin's claimed motion changes.
    parts = [SimPart(sp.link, sp.joint, np.asarray(ALL_PARTS[sp.link][1].vertices) - ALL_PARTS[sp.link][0].pivot)
             for sp in _sim_parts(shifted)]
    for r in check_in_simulators(*files, parts):
        print(r.simulator, r.status, {k: f"{v * 1e3:.2f} mm" for k, v in r.part_errors_m.items()})
        assert r.status == "mismatch", r
        # The link origin is 1 cm off at every q: at least that, plus the swing (q <= 1.3 rad).
        assert 9.9e-3 < r.part_errors_m["door"] < 3e-2
        assert r.part_errors_m["drawer"] < 1e-6  # the other parts are untouched


def test_missing_packages_and_files_are_notes_not_exceptions(files, monkeypatch, tmp_path):
    real = _simcheck.importlib.util.find_spec
    monkeypatch.setattr(_simcheck.importlib.util, "find_spec", lambda n: None if n == "pybullet" else real(n))
    results = {r.simulator: r for r in check_in_simulators(files[0], tmp_path / "missing.xml", _sim_parts())}
    assert results["pybullet"].status == "skipped" and "pybullet" in results["pybullet"].note
    assert results["mujoco_mjcf"].status == "failed" and "missing.xml" in results["mujoco_mjcf"].note
    assert results["yourdfpy"].status == "ok" and results["mujoco_urdf"].status == "ok"
    assert np.isnan(results["pybullet"].max_error_m) and results["pybullet"].to_json()["max_error_mm"] is None
    none = {r.simulator: r for r in check_in_simulators(None, files[1], _sim_parts())}
    assert none["yourdfpy"].status == "skipped" and "no URDF" in none["yourdfpy"].note
    assert none["mujoco_mjcf"].status == "ok"
