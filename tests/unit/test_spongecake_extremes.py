"""Extreme parameters and directions: every output finite and non-negative, without a numpy warning."""
import itertools

import numpy as np
import pytest

from addon.reference import frames, spongecake

COSINES = (1.0, 1e-7, 0.0, -0.0, -1e-7, -1.0)
DIRECTIONS = frames.spherical(np.repeat(COSINES, 2), np.tile([0.0, 2.2], len(COSINES)))
U = np.array(list(itertools.product((0.0, 0.5, np.nextafter(1.0, 0.0)), repeat=3)))

FLAKES = [dict(type=t, roughness=a, f0=f0, orientation=o) for t, a, f0, o in itertools.product(
    ("surface", "fiber"), (1e-4, 1.0), ([0, 0, 0], [1, 1, 1]), ([0, 0, 1], [1, 0, 0]))]
LAYERS = FLAKES + [dict(type="hg", roughness=g) for g in (-0.99, 0.99)]
STACKS = {
    "alone": {},
    "delta": dict(delta_transmission=True),
    "over hg": dict(below=dict(type="hg", roughness=0.5, thickness=0.1)),
    "diffuse": dict(substrate=dict(type="diffuse")),
    "conductor": dict(substrate=dict(type="conductor", roughness=1e-4)),
    "smooth dielectric": dict(substrate=dict(type="dielectric", roughness=1e-4)),
    "rough dielectric": dict(substrate=dict(type="dielectric", roughness=1.0)),
}


def _params(layer, thickness, stack):
    stack = dict(stack)
    layers = [dict(layer, thickness=thickness)] + ([stack.pop("below")] if "below" in stack else [])
    return spongecake.params_from_dict(dict(layers=layers, **stack))


def _check(*arrays):
    for a in arrays:
        assert np.all(np.isfinite(a)) and np.all(a >= 0)


@pytest.mark.parametrize("thickness", [1e-6, 1e3, 1e4])
@pytest.mark.parametrize("layer", LAYERS, ids=lambda d: "-".join(str(v) for v in d.values()))
def test_every_output_is_finite_and_non_negative(layer, thickness):
    wi = np.repeat(DIRECTIONS, len(DIRECTIONS), 0)
    wo = np.tile(DIRECTIONS, (len(DIRECTIONS), 1))
    for stack in STACKS.values():
        p = _params(layer, thickness, stack)
        with np.errstate(divide="raise", over="raise", invalid="raise"):
            _check(spongecake.eval(p, wi, wo), spongecake.pdf(p, wi, wo), spongecake.delta_transmittance(p, DIRECTIONS))
            s = spongecake.sample(p, np.repeat(DIRECTIONS, len(U), 0), np.tile(U, (len(DIRECTIONS), 1)))
            _check(s.weight, s.pdf)
            assert np.allclose(np.linalg.norm(s.wo, axis=1), 1.0, atol=1e-9)
            _check(*spongecake.ground_truth(p, wi, wo, n_paths=8, seed=0, max_depth=4))


@pytest.mark.usefixtures("coarse_energy_tables")
@pytest.mark.parametrize("thickness", [1e-6, 1e4])
@pytest.mark.parametrize("layer", LAYERS, ids=lambda d: "-".join(str(v) for v in d.values()))
def test_multiple_scattering_lobes_are_finite_and_non_negative(layer, thickness):
    wi = np.repeat(DIRECTIONS, len(DIRECTIONS), 0)
    wo = np.tile(DIRECTIONS, (len(DIRECTIONS), 1))
    for stack in STACKS.values():
        p = spongecake.params_from_dict(dict(_params(layer, thickness, stack).to_dict(), multiple_scattering=True))
        with np.errstate(divide="raise", over="raise", invalid="raise"):
            _check(spongecake.eval(p, wi, wo))


@pytest.mark.parametrize("layer", [LAYERS[0], LAYERS[7], LAYERS[-1]], ids=["surface", "fiber", "hg"])
def test_directional_albedo_at_extremes(layer):
    for thickness, stack in itertools.product((1e-6, 1e4), STACKS.values()):
        p = _params(layer, thickness, stack)
        with np.errstate(divide="raise", over="raise", invalid="raise"):
            albedo = spongecake.directional_albedo(p, DIRECTIONS, n=64)
        _check(albedo)
