"""OpenMP threads wait by sleeping, not spinning, unless the user says otherwise (``artitwin_core``
sets ``OMP_WAIT_POLICY`` before any OpenMP runtime loads: spinning threads made Open3D's TSDF
integration 70 times slower on two shared cores, docs/performance.md)."""

from __future__ import annotations

import os
import subprocess
import sys

import pytest

SHOW = "import artitwin_core, os; print(os.environ.get('OMP_WAIT_POLICY'))"


@pytest.mark.parametrize(("given", "expected"), [(None, "PASSIVE"), ("ACTIVE", "ACTIVE")])
def test_wait_policy_defaults_to_passive_and_the_user_wins(given, expected):
    env = {k: v for k, v in os.environ.items() if k != "OMP_WAIT_POLICY"}
    if given is not None:
        env["OMP_WAIT_POLICY"] = given
    out = subprocess.run([sys.executable, "-c", SHOW], env=env, capture_output=True, text=True, check=True)
    assert out.stdout.strip() == expected
