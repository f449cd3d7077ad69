"""The analytic thin-coat model against the independent Monte Carlo ground truth, per bounce order
(``bench_thin_coat.truth_rows``; the full grid of the issue is in docs/accuracy.md, made by ``make bench``).

Measured with 20 000 paths (relative errors model / truth − 1; κ the moment-matched width of the exit directions):

    κ1, κ2       θo   order | energy    κ        peak
    1e3, 1e3      0°    1   |  0.0 %   −0.5 %   +2.6 %
                        2   | −0.1 %   +2.6 %   −0.2 %
                 60°    1   | +10.3 %  −17 %    −4.1 %
                        2   |  −8.3 %  −30 %   −24 %
    1e4, 1e3      0°    1   |  0.0 %   −0.9 %   −3.5 %
                 60°    1   |  +7.3 %  −12 %    −9.8 %

At normal view the mean-path model is exact in energy; at oblique views the internal lobe's tail crosses the
critical angle and higher Fresnel values, which the remaining terms taken at the mean directions (Sec. 5.1) do
not see, and the isotropic lobe cannot follow the anisotropic exact lobe (Figs. 6-7). Bounds: measured + 25 %
+ 2 percentage points, and for peaks also 3 standard errors of the next-event estimate.
"""
import numpy as np
import pytest

from addon.bench import thin_coat as bench_thin_coat
from addon.models.thin_coat import params_from_dict

CASES = ((1e3, 1e3), (1e4, 1e3))
BOUNDS = {  # (κ1, θo, order): (energy, κ, peak) relative-error bounds
    (1e3, 0.0, 1): (0.02, 0.026, 0.052), (1e3, 0.0, 2): (0.02, 0.053, 0.023),
    (1e3, 60.0, 1): (0.15, 0.23, 0.071), (1e3, 60.0, 2): (0.12, 0.40, 0.32),
    (1e4, 0.0, 1): (0.02, 0.031, 0.064), (1e4, 60.0, 1): (0.11, 0.17, 0.14),
}


@pytest.fixture(scope="module")
def rows():
    grid = [params_from_dict({"kappa_top": k1, "kappa_bottom": k2, "bounces": 2}) for k1, k2 in CASES]
    return bench_thin_coat.truth_rows(paths=20000, grid=grid)


@pytest.mark.parametrize("key", sorted(BOUNDS))
def test_model_follows_the_ground_truth(rows, key):
    k1, theta, order = key
    r = next(r for r in rows if r["k1"] == k1 and r["theta"] == theta and r["order"] == order)
    energy, kappa, peak = BOUNDS[key]
    print(key, r)
    assert abs(r["energy"] / r["energy_gt"] - 1) < energy + 3 * r["energy_se"] / r["energy_gt"]
    assert abs(r["kappa"] / r["kappa_gt"] - 1) < kappa
    assert abs(r["peak"] / r["peak_gt"] - 1) < peak + 3 * r["peak_se"] / r["peak_gt"]


def test_eq8_masking_against_the_exact_integral():
    """Eq. 8's projected area against the exact integral (``thin_coat_truth.projected_area_exact``), the paper's
    Fig. 2 claim. Measured worst relative error: 4.6 % up to θ = 60° (κ = 10), 7.2 % up to 80°, but 54 % at
    θ = 89° (κ = 100), where Eq. 8's G1 is 0.77 against the exact 0.35: the approximation fails at grazing
    views, which the paper's Fig. 2 does not show. Exact at κ → 0 (1/4) and κ → ∞ (cos θ)."""
    rows = bench_thin_coat.masking_rows()
    errs = {(r["kappa"], r["theta"]): abs(r["eq8"] / r["exact"] - 1) for r in rows}
    assert max(e for (k, t), e in errs.items() if t <= 60) < 0.06
    assert max(e for (k, t), e in errs.items() if t <= 80) < 0.09
    assert 0.4 < errs[(100.0, 89.0)] < 0.7  # the grazing failure stated in docs/accuracy.md
    assert errs[(1e-3, 0.0)] < 1e-3 and errs[(1e6, 60.0)] < 1e-5
    assert all(abs(r["g1_eq8"] - r["g1_exact"]) < 0.08 for r in rows if r["theta"] <= 80)
    assert all(0 <= r["g1_eq8"] <= 1 and np.isfinite(r["eq8"]) for r in rows)
