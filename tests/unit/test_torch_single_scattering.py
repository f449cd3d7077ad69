"""The differentiable torch single scattering (training/spongecake_torch.py) against the float64 numpy reference,
and its gradients (gradcheck, finiteness at extremes)."""
import numpy as np
import pytest

torch = pytest.importorskip("torch")

from addon.models.spongecake import Layer, Params  # noqa: E402
from addon.reference import spongecake as ref  # noqa: E402
from training.spongecake_torch import LayerBatch, eval_stack, from_params  # noqa: E402

FIELDS = ("roughness", "albedo", "thickness", "f0", "orientation")


def _unit(rng, n):
    v = rng.normal(size=(n, 3))
    return v / np.linalg.norm(v, axis=1, keepdims=True)


def _random_layer(rng, kind=None):
    kind = kind or rng.choice(["surface", "fiber", "hg"])
    roughness = rng.uniform(-0.95, 0.95) if kind == "hg" else 10.0 ** rng.uniform(-3.0, 0.0)
    f0 = (1.0, 1.0, 1.0) if rng.random() < 0.5 else tuple(rng.uniform(0.0, 1.0, 3))
    return Layer(str(kind), float(roughness), tuple(rng.uniform(0.0, 1.0, 3)), float(10.0 ** rng.uniform(-3.0, 3.0)),
                 f0, tuple(_unit(rng, 1)[0]))


def _directions(rng, n):
    """Random pairs in both hemispheres (reflection and transmission, either side), a few near grazing
    (|cos| = 1e-4) and a few exact back-scattering pairs wo = -wi (no half vector)."""
    wi, wo = _unit(rng, n), _unit(rng, n)
    near = rng.choice([-1e-4, 1e-4], size=(4, 1))
    tangent = _unit(rng, 4) * [1.0, 1.0, 0.0]
    tangent /= np.linalg.norm(tangent, axis=1, keepdims=True)
    wi[:4] = np.sqrt(1.0 - near ** 2) * tangent + near * [0.0, 0.0, 1.0]
    wo[4:8] = -wi[4:8]
    return wi, wo


@pytest.mark.parametrize("n_layers", [1, 2])
def test_matches_numpy_reference(n_layers):
    rng = np.random.default_rng(100 + n_layers)
    params = [Params(tuple(_random_layer(rng) for _ in range(n_layers))) for _ in range(300)]
    wi, wo = _directions(rng, 64)
    up_i, up_o = wi[:, 2] > 0, wo[:, 2] > 0
    assert {(a, b) for a, b in zip(up_i, up_o)} == {(True, True), (True, False), (False, True), (False, False)}

    got = eval_stack(from_params(params), torch.from_numpy(wi), torch.from_numpy(wo)).numpy()
    want = np.stack([ref.eval(p, wi, wo) for p in params])
    assert got.shape == (len(params), len(wi), 3)
    np.testing.assert_allclose(got, want, rtol=1e-6, atol=1e-12)
    # most of the values are far above atol: the comparison is not vacuous
    assert np.mean(want > 1e-6) > 0.3
    # (N, 3) and (B, N, 3) directions agree
    batched = eval_stack(from_params(params[:3]), torch.from_numpy(np.broadcast_to(wi, (3,) + wi.shape).copy()),
                         torch.from_numpy(wo))
    np.testing.assert_allclose(batched.numpy(), got[:3], rtol=1e-14, atol=0)


def _leaf_layers(specs):
    """LayerBatch list from per-layer lists of (kind, roughness, albedo, thickness, f0, orientation) rows."""
    layers = []
    for rows in specs:
        params = [Params((Layer(*row),)) for row in rows]
        layers.append(from_params(params)[0])
    return layers


def _with(layers, leaves):
    """Copies of ``layers`` whose differentiable fields are the given tensors (5 per layer, FIELDS order)."""
    out = []
    for k, layer in enumerate(layers):
        values = dict(zip(FIELDS, leaves[5 * k: 5 * k + 5]))
        out.append(LayerBatch(kind=layer.kind, **values))
    return out


def test_gradcheck():
    specs = [
        [("surface", 0.3, (0.8, 0.5, 0.2), 0.7, (0.04, 0.5, 0.9), (0.2, -0.1, 0.97)),
         ("hg", 0.4, (0.6, 0.7, 0.9), 1.3, (1.0, 1.0, 1.0), (0.0, 0.0, 1.0))],
        [("fiber", 0.5, (0.9, 0.9, 0.3), 2.0, (1.0, 1.0, 1.0), (0.6, 0.3, 0.74)),
         ("surface", 0.15, (0.4, 0.6, 0.8), 0.4, (0.2, 0.3, 0.4), (-0.3, 0.2, 0.93))],
    ]
    layers = _leaf_layers(specs)
    leaves = [getattr(layer, f).clone().requires_grad_(True) for layer in layers for f in FIELDS]
    rng = np.random.default_rng(7)
    wi, wo = _unit(rng, 4), _unit(rng, 4)
    wi[:, 2], wo[:2, 2], wo[2:, 2] = np.abs(wi[:, 2]) + 0.2, np.abs(wo[:2, 2]) + 0.2, -np.abs(wo[2:, 2]) - 0.2
    wi, wo = (torch.from_numpy(w / np.linalg.norm(w, axis=1, keepdims=True)) for w in (wi, wo))

    def f(*x):
        return eval_stack(_with(layers, x), wi, wo)

    assert torch.autograd.gradcheck(f, leaves, eps=1e-6, atol=1e-7, rtol=1e-5)


def test_gradients_finite_at_extremes():
    rows = []
    for kind, r in (("surface", 0.01), ("fiber", 0.2), ("hg", -0.7), ("hg", 0.0), ("surface", 1.0)):
        for thickness in (1e4, 1e-3):
            rows.append((kind, r, (0.7, 0.8, 0.9), thickness, (0.1, 0.2, 0.3), (0.3, 0.1, 0.95)))
    top = rows
    bottom = rows[::-1]
    layers = _leaf_layers([top, bottom])
    leaves = [getattr(layer, f).clone().requires_grad_(True) for layer in layers for f in FIELDS]

    s = np.sqrt(1.0 - 1e-12)
    wi = np.array([[s, 0, 1e-6], [s, 0, 1e-6], [0, s, -1e-6], [0.6, 0, 0.8], [0.6, 0, 0.8], [1.0, 0, 0.0],
                   [0.6, 0, 0.8], [0.0, 0.6, -0.8]])
    wo = np.array([[0, s, 1e-6], [0, -s, -1e-6], [0.6, 0, -0.8], [s, 0, -1e-6], [0, 0.6, 0.8], [0.6, 0, 0.8],
                   [-0.6, 0, -0.8], [0.0, 0.6, 0.8]])
    f = eval_stack(_with(layers, leaves), torch.from_numpy(wi), torch.from_numpy(wo))
    assert torch.isfinite(f).all()
    assert (f[:, 5] == 0).all()  # exactly grazing
    f.sum().backward()
    for leaf in leaves:
        assert torch.isfinite(leaf.grad).all()
    # single layer too (no attenuation by another layer)
    leaves = [getattr(layers[0], fld).clone().requires_grad_(True) for fld in FIELDS]
    eval_stack(_with(layers[:1], leaves), torch.from_numpy(wi), torch.from_numpy(wo)).sum().backward()
    for leaf in leaves:
        assert torch.isfinite(leaf.grad).all()
