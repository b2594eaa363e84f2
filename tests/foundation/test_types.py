"""The type checker over the core packages whose types are kept clean.

mypy runs with pyproject.toml's ``[tool.mypy]`` settings (third-party packages without stubs are
``Any``; imports outside the list are read but not reported). The list grows as packages are
cleaned; each one costs a few seconds of the suite (all three: about 10 s of CPU with a warm
cache, 40 s cold, on one core).
"""

from __future__ import annotations

import pathlib

import pytest

api = pytest.importorskip("mypy.api", reason="mypy is not installed (pip install -e '.[test]')")

ROOT = pathlib.Path(__file__).resolve().parents[2]
CHECKED = ["artitwin_core/joints", "artitwin_core/parts", "artitwin_core/geometry"]


@pytest.mark.slow
def test_the_checked_packages_have_no_type_errors(tmp_path_factory):
    cache = tmp_path_factory.getbasetemp().parent / "mypy-cache"
    stdout, stderr, status = api.run(
        ["--config-file", str(ROOT / "pyproject.toml"), "--cache-dir", str(cache), *(str(ROOT / p) for p in CHECKED)]
    )
    assert status == 0, f"mypy found type errors (run: mypy {' '.join(CHECKED)}):\n{stdout}{stderr}"
