"""The anisotropic-stack model against the Monte Carlo ground truth through the explicit stack, on a small version of
the benchmark's grid (``addon.bench.aniso_stack``; docs/accuracy.md has the 200-stack table). Bounds are the
measured medians of this grid (seed 21, 8 stacks × 3 views) with a margin; a broken adding loop (e.g. lobes on the
wrong axis or energies without the inter-reflection denominator) exceeds them."""
import math

import numpy as np
import pytest

from addon.bench import aniso_stack as bench
from addon.models import aniso_stack as model
from addon.reference import aniso_stack as reference


@pytest.fixture(scope="module")
def grid():
    return bench.summary(bench.grid_rows(n_stacks=8, paths=20000))


def test_lobe_axes_follow_the_truth(grid):
    assert grid["main"]["axis"][0] < 3.0  # degrees, median (measured 1.3)
    assert grid["all"]["axis"][1] < 12.0  # 90th percentile (measured 5.9)


def test_lobe_energies_and_widths_are_close_away_from_the_rim(grid):
    main = grid["main"]
    assert main["lobes"] >= 10
    assert main["energy"][0] < 0.15  # median |relative error| (measured 0.06)
    assert main["major"][0] < 0.10 and main["minor"][0] < 0.20  # (measured 0.04, 0.10)
    assert main["albedo"][0] < 0.25  # the model's T = 1 - R keeps what masking removes in the stack (measured 0.13)


def test_model_lobe_statistics_of_a_single_interface_match_its_own_brdf():
    """A lone conductor: the model is exactly the microfacet BRDF, so its lobe statistics are the truth's within the
    Monte Carlo noise of both."""
    p = model.params_from_dict({"interfaces": [{"type": "conductor", "alpha": [0.3, 0.06], "rotation": 40.0}]})
    wo = np.array([math.sin(0.5), 0.0, math.cos(0.5)])
    wo_n = np.tile(wo, (50_000, 1))
    (lobe,) = reference.lobes_at(p, wo_n)
    m = bench.model_lobe_stats(p, lobe, wo_n, np.random.default_rng(3))
    from addon.reference import aniso_stack_truth as truth

    t = truth.exit_lobes(p, wo, n_paths=50_000, seed=4)["interfaces"][0]
    np.testing.assert_allclose(m["energy"], t["energy"], rtol=0.02)
    axis_m, major_m, minor_m = bench._axis_and_widths(m["cov"])
    axis_t, major_t, minor_t = bench._axis_and_widths(t["cov"])
    assert bench._axis_gap(axis_m, axis_t) < 2.0
    assert major_m == pytest.approx(major_t, rel=0.03) and minor_m == pytest.approx(minor_t, rel=0.05)
