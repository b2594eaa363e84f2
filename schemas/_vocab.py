"""The closed vocabularies the artifacts and configs share with the core, as ``Literal`` types.

The core declares each once (``artitwin_core.joints.JointType``, ``artitwin_core.parts.Fate``,
``artitwin_core.gaussians.BackendName``); schemas does not import the core, so they are written
again here and ``tests/foundation/test_config_truth.py`` checks that the two agree.
"""

from __future__ import annotations

from typing import Literal

JointType = Literal["revolute", "prismatic", "screw", "fixed"]
Fate = Literal["kept", "merged", "dropped"]
BackendName = Literal["auto", "cpu", "reference", "cuda"]
