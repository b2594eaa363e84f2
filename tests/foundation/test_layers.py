"""Imports point one way (../shared/STYLE.md), checked by import-linter's contracts in pyproject.toml."""

from __future__ import annotations

import os
import shutil
import subprocess
import sys
from pathlib import Path

import pytest

REPO = Path(__file__).resolve().parents[2]
PACKAGES = ["artitwin", "artitwin_core", "schemas", "tasks", "flows", "infra"]
LINT = str(Path(sys.executable).parent / "lint-imports")


def _lint(root: Path) -> subprocess.CompletedProcess:
    env = {**os.environ, "PYTHONPATH": str(root)}
    # No cache: a cache left by an earlier run can report imports that were since removed.
    return subprocess.run([LINT, "--no-cache"], cwd=root, env=env, capture_output=True, text=True, timeout=300)


def test_the_codebase_keeps_its_import_contracts():
    result = _lint(REPO)
    assert result.returncode == 0, result.stdout[-3000:] + result.stderr[-2000:]
    assert "0 broken" in result.stdout


@pytest.mark.parametrize(
    "module, source, contract",
    [
        ("artitwin_core/_bad.py", "import prefect\n", "The core is pure"),
        ("artitwin_core/_bad.py", "import zarr\n", "The core is pure"),
        ("artitwin_core/_bad.py", "import pydantic\n", "The core is pure"),
        ("tasks/_bad.py", "import flows\n", "Layers"),
        ("schemas/_bad.py", "import artitwin_core\n", "Layers"),
        ("tasks/_bad.py", "from prefect import task\n", "callable without Prefect"),
    ],
)
def test_a_violation_is_caught(tmp_path, module, source, contract):
    for pkg in PACKAGES:
        shutil.copytree(REPO / pkg, tmp_path / pkg, ignore=shutil.ignore_patterns("__pycache__"))
    shutil.copy(REPO / "pyproject.toml", tmp_path / "pyproject.toml")
    (tmp_path / module).write_text(source)
    result = _lint(tmp_path)
    assert result.returncode != 0
    broken = [line for line in result.stdout.splitlines() if "BROKEN" in line]
    assert any(contract in line for line in broken) or contract in result.stdout.split("Broken contracts")[-1], result.stdout[-2000:]


def test_an_import_cycle_is_caught(tmp_path):
    for pkg in PACKAGES:
        shutil.copytree(REPO / pkg, tmp_path / pkg, ignore=shutil.ignore_patterns("__pycache__"))
    shutil.copy(REPO / "pyproject.toml", tmp_path / "pyproject.toml")
    (tmp_path / "artitwin_core/joints/_bad.py").write_text("from artitwin_core.joints import _types\n")
    (tmp_path / "artitwin_core/joints/_types.py").write_text(
        (REPO / "artitwin_core/joints/_types.py").read_text() + "\nfrom artitwin_core.joints import _bad  # noqa\n"
    )
    result = _lint(tmp_path)
    assert result.returncode != 0
    assert "No cycles are allowed in artitwin_core.joints" in result.stdout, result.stdout[-2000:]
