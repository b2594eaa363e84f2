"""Part brightness curves: pinned to 1 when closed, piecewise linear in log gain, and scaling the
rendered colour of exactly the part's Gaussians."""

from __future__ import annotations

import numpy as np
import pytest
import torch

from artitwin_core._errors import InputError
from artitwin_core.articulation import PartAppearance
from artitwin_core.articulation._appearance import apply_part_gains, part_log_gains
from artitwin_core.gaussians import LABEL_BACKGROUND, LABEL_INTERIOR, LABEL_PART
from artitwin_core.gaussians._sh import eval_sh_colors


def test_the_closed_state_has_gain_one_and_knots_interpolate_linearly_in_log_gain():
    q = np.array([[0.0, 0.0], [0.4, -0.1], [1.2, -0.2]])
    a = PartAppearance.neutral(q, 4)
    np.testing.assert_allclose(a.knots[0], [0.0, 0.4, 0.8, 1.2])
    np.testing.assert_allclose(a.knots[1], np.linspace(-0.2, 0.0, 4))
    a = PartAppearance(a.knots, np.array([[0.3, -0.2, -0.6, -1.0], [0.5, 0.2, 0.1, 0.7]]))
    # Part 0's knot at q = 0 carries 0.3, part 1's carries 0.7: both are subtracted (pinning).
    np.testing.assert_allclose(a.gains([0.0, 0.0]), [1.0, 1.0], atol=1e-12)
    np.testing.assert_allclose(np.log(a.gains([0.6, -0.2])), [-0.4 - 0.3, 0.5 - 0.7], atol=1e-12)
    # Held constant outside the knots.
    np.testing.assert_allclose(a.gains([5.0, -3.0]), a.gains([1.2, -0.2]), atol=1e-12)
    with pytest.raises(InputError, match="ascending"):
        PartAppearance(np.array([[0.0, 0.0]]), np.zeros((1, 2)))


def test_part_gains_scale_the_evaluated_colour_of_part_gaussians_only():
    rng = np.random.default_rng(0)
    n = 40
    sh = torch.from_numpy(rng.normal(0, 0.4, (n, 4, 3)))
    labels = torch.from_numpy(rng.choice([LABEL_BACKGROUND, LABEL_INTERIOR, LABEL_PART, LABEL_PART + 1], n))
    dirs = torch.from_numpy(rng.normal(size=(n, 3)))
    dirs = dirs / dirs.norm(dim=1, keepdim=True)
    log_g = torch.tensor([np.log(0.37), np.log(1.6)], dtype=torch.float64, requires_grad=True)
    before = eval_sh_colors(sh, dirs, 1)
    after = eval_sh_colors(apply_part_gains(sh, labels, log_g), dirs, 1)
    # eval_sh_colors returns max(0.5 + SH(d), 0): a positive gain scales it exactly.
    factor = torch.ones(n, dtype=torch.float64)
    factor[labels == LABEL_PART] = 0.37
    factor[labels == LABEL_PART + 1] = 1.6
    torch.testing.assert_close(after, before * factor[:, None], atol=1e-12, rtol=0)
    # Gradients reach the log gains through the interpolation.
    knots = np.array([[0.0, 1.0], [0.0, 1.0]])
    lg = part_log_gains(torch.zeros((2, 2), dtype=torch.float64, requires_grad=True), knots, [0.5, 1.0])
    lg.sum().backward()
    assert lg.shape == (2,)
