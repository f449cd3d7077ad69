"""Train the SpongeCake multiple-scattering networks (Wang et al. 2022, Sec. 5 "Training") and export them.

One MLP per layer count: ``L * FEATURES`` inputs, three hidden layers of 128 SiLU units (``--hidden``; the shipped
two-layer network has 192),
``L * OUTPUTS + WEIGHT_OUTPUTS + FORWARD_OUTPUTS`` outputs (``addon.bake.spongecake`` documents the encoding). SiLU rather than ReLU: the predicted parameters
are then smooth (C-infinity) functions of the layer parameters, so texture-driven bakes vary smoothly between
texels, and no unit dies on a small dataset. Loss: MAE between the Monte Carlo multiple-scattering lobe and
W1 f_ss(params') + W2 / pi + f_ss(forward), both times |cos wo| (the differentiable ``training.spongecake_torch.eval_stack``),
AdamW (weight decay 1e-4), learning rate 1e-3 (``--learning-rate``) with cosine decay, the checkpoint with the best split-validation
loss kept, mini-batches of 32 configurations (every direction pair of a
configuration in the same batch). 10% of the configurations are held out for validation (the same ones for every ``--seed``: ``SPLIT_SEED``); the shipped,
independently seeded validation set (tests/data) is scored at export and its errors go into the manifest.

    python -m training.train --data ~/.cache/lamina/spongecake-ms --layers 1 --threads 1 --minutes 30 --out addon/bake/weights
    python -m training.train --data /tmp/quick --quick --out /tmp/weights             # seconds, for tests
    python -m training.train --layers 2 --ensemble <run of --seed 0> <run of --seed 1> --out <folder>

``--area`` trains the form with the area exponents: the forward lobe scaled by the layers' projected areas along
wi and wo, each to a power the network predicts (``area_scale``; one output per layer after the others;
docs/training.md measures the form's bound). Both shipped networks have it; ``addon.bake.spongecake.decode`` reads
either form. ``--ensemble`` writes the mean of runs as one network (``export_ensemble``).
"""
from __future__ import annotations

import argparse
import dataclasses
import datetime
import json
import math
import os
import subprocess
import sys
import time
from pathlib import Path

import numpy as np
import torch

from addon.bake import layer_rows, mlp, validation
from addon.bake import spongecake as ms
from training import dataset
from training.spongecake_torch import LayerBatch, eval_stack, projected_area

HIDDEN = (128, 128, 128)
LEARNING_RATE = 1e-3
WEIGHT_DECAY = 1e-4  # AdamW; a few thousand configurations per network: keep the 3x128 MLP from memorising them
SPLIT_SEED = 0  # which configurations are held out for split validation: the same whatever --seed
ENERGY_WEIGHT = 2.0  # energy matters most in renders (and the furnace); see lobe_loss
ENERGY_FLOOR = 1e-3  # about the median configuration's mean f |cos wo| of multiple scattering in the dataset
VALIDATION_SET = Path(__file__).resolve().parents[1] / "tests" / "data" / "spongecake_ms_validation"
DEVICE = torch.device("cpu")  # where training runs (``--device``); the exported weights are numpy either way
PRECISION = torch.float64  # what training computes in (``--float32``); the exported weights are float32 either way


class TorchOps:
    exp, tanh, sqrt, log, sigmoid, clip = torch.exp, torch.tanh, torch.sqrt, torch.log, torch.sigmoid, torch.clamp
    softplus = staticmethod(torch.nn.functional.softplus)

    @staticmethod
    def where(c, a, b):
        return torch.where(c, a, b)

    @staticmethod
    def any_last(x):
        return x.any(-1, keepdim=True)

    @staticmethod
    def sum_last(x):
        return x.sum(-1, keepdim=True)

    @staticmethod
    def stack(parts, axis):
        return torch.stack(parts, dim=axis)

    @staticmethod
    def concat(parts, axis):
        return torch.cat(parts, dim=axis)


# The forward lobe's raw outputs at the start: g = 0.98 tanh(1) = 0.75, albedo softplus(-5) ≈ 0.007, T rho 1.
FORWARD_START = (1.0, -5.0, -5.0, -5.0, 0.0)
AREA_START = -8.0  # the area exponents' raw start (``--area``): softplus(-8) = 3e-4, the forward lobe as it is


def outputs(n_layers: int, area: bool = False) -> int:
    """Raw outputs of a network for ``n_layers``: with the forward lobe, plus one area exponent per layer with
    ``area`` (``bake.spongecake.output_widths``)."""
    return ms.output_widths(n_layers)[2 if area else 1]


def silu_mlp(sizes) -> torch.nn.Sequential:
    """Linear layers of ``sizes`` with SiLU between them, the last one's weights scaled by 0.1 (outputs start near
    its bias, which the caller sets): both trainers' networks (this one and ``training.energy_train``)."""
    modules = []
    for i in range(len(sizes) - 1):
        modules.append(torch.nn.Linear(sizes[i], sizes[i + 1]))
        if i + 2 < len(sizes):
            modules.append(torch.nn.SiLU())
    with torch.no_grad():
        modules[-1].weight.mul_(0.1)
    return torch.nn.Sequential(*modules)


def make_network(n_layers: int, area: bool = False, hidden: tuple = HIDDEN) -> torch.nn.Sequential:
    net = silu_mlp((n_layers * ms.FEATURES, *hidden, outputs(n_layers, area)))
    last = net[-1]
    forward = n_layers * ms.OUTPUTS + ms.WEIGHT_OUTPUTS
    with torch.no_grad():
        last.bias.zero_()
        last.bias[n_layers * ms.OUTPUTS:forward] = -5.0  # start with small lobes
        last.bias[forward:forward + ms.FORWARD_OUTPUTS] = torch.tensor(FORWARD_START)
        last.bias[outputs(n_layers):] = AREA_START
    return net.to(DEVICE, PRECISION)


def warm_start(net: torch.nn.Sequential, shipped: mlp.MLP) -> None:
    """Load an exported network's weights into ``net`` (training goes on from it). A network exported before the
    forward lobe has FORWARD_OUTPUTS fewer outputs, one without the area exponents (``--area``) one per layer fewer:
    those start as ``make_network`` starts them, so the warm-started network predicts what ``shipped`` predicts, plus
    a faint forward lobe (albedo about 0.007) and areas to the power 3e-4."""
    linears = [m for m in net if isinstance(m, torch.nn.Linear)]
    sizes = [(m.weight.shape[1], m.weight.shape[0]) for m in linears]
    shipped_sizes = [w.shape for w in shipped.weights]
    n_layers = sizes[0][0] // ms.FEATURES
    ends = [n_layers * ms.OUTPUTS + ms.WEIGHT_OUTPUTS, outputs(n_layers), outputs(n_layers, area=True)]
    known = [sizes[:-1] + [(sizes[-1][0], end)] for end in ends if end <= sizes[-1][1]]
    if shipped_sizes not in known:
        raise ValueError(f"the warm-start network's layers {shipped_sizes} are neither this network's {sizes} nor "
                         f"those without the forward lobe or the area exponents")
    with torch.no_grad():
        for m, w, b in zip(linears, shipped.weights, shipped.biases):
            m.weight[:w.shape[1]] = torch.as_tensor(w.T)
            m.bias[:b.shape[0]] = torch.as_tensor(b)


def to_mlp(net: torch.nn.Sequential, manifest: dict) -> mlp.MLP:
    linears = [m for m in net if isinstance(m, torch.nn.Linear)]
    return mlp.MLP(tuple(m.weight.detach().cpu().numpy().T.copy() for m in linears),
                   tuple(m.bias.detach().cpu().numpy().copy() for m in linears), manifest)


# ------------------------------------------------------------------------------------------------ loss

def layer_batch(rows: torch.Tensor) -> LayerBatch:
    """One layer's rows (B, ROW) as a LayerBatch."""
    return LayerBatch(kind=rows[:, layer_rows.TYPE].round().long(), roughness=rows[:, layer_rows.ROUGHNESS],
                      albedo=rows[:, layer_rows.ALBEDO], thickness=rows[:, layer_rows.THICKNESS],
                      f0=rows[:, layer_rows.F0], orientation=rows[:, layer_rows.ORIENTATION])


def all_pairs(wi: torch.Tensor, wo: torch.Tensor):
    """Every (wi, wo) pair of B configurations' (B, n_wi, 3) and (B, n_wo, 3) directions: two (B, n_wi n_wo, 3)."""
    b, n_wi, n_wo = wi.shape[0], wi.shape[1], wo.shape[1]
    return (wi[:, :, None, :].expand(b, n_wi, n_wo, 3).reshape(b, -1, 3),
            wo[:, None, :, :].expand(b, n_wi, n_wo, 3).reshape(b, -1, 3))


def forward_lobe(weights: torch.Tensor, big_wi: torch.Tensor, big_wo: torch.Tensor) -> torch.Tensor:
    """f_ss(forward) (B, N, 3), no cosine: the decoded weights' forward lobe, one hg layer."""
    b = weights.shape[0]
    forward = LayerBatch(kind=torch.full((b,), 2, dtype=torch.long, device=weights.device),
                         roughness=weights[:, ms.FORWARD_G], albedo=weights[:, ms.FORWARD_ALBEDO],
                         thickness=weights[:, ms.FORWARD_THICKNESS], f0=torch.ones_like(weights[:, ms.FORWARD_ALBEDO]),
                         orientation=torch.ones_like(weights[:, ms.FORWARD_ALBEDO]))  # ignored by hg layers
    return eval_stack([forward], big_wi, big_wo)


def area_scale(rows: torch.Tensor, exponents: torch.Tensor, big_wi: torch.Tensor, big_wo: torch.Tensor):
    """Π_k (σ_k(wi) σ_k(wo))^p_k (B, N): the layers' projected areas (``rows`` as given; 1 for hg layers) to the
    powers ``exponents`` (B, L). Reciprocal; exponents 0 give 1."""
    log_scale = 0.0
    for k in range(rows.shape[1]):
        layer = layer_batch(rows[:, k])
        areas = projected_area(layer, big_wi) * projected_area(layer, big_wo)
        log_scale = log_scale + exponents[:, k:k + 1] * torch.log(areas.clamp_min(1e-12))
    return torch.exp(log_scale)


def predicted_lobe(net, rows: torch.Tensor, wi: torch.Tensor, wo: torch.Tensor) -> torch.Tensor:
    """W1 f_ss(params') + W2 / pi + f_ss(forward) for B configurations at their (n_wi x n_wo) pairs, times |cos wo|:
    (B, n_wi, n_wo, 3); a network with the area exponents (``--area``) scales the forward lobe by ``area_scale``
    (light that two flakes of one orientation send on close to its own direction grows with the flakes' area seen
    along it, which an hg lobe of one mean cosine does not follow)."""
    x = torch.as_tensor(ms.features(rows.cpu().numpy()), dtype=rows.dtype, device=rows.device)
    raw = net(x)
    lobe, weights = ms.decode(raw, rows, TorchOps)
    big_wi, big_wo = all_pairs(wi, wo)
    forward = forward_lobe(weights, big_wi, big_wo)
    if raw.shape[1] > outputs(rows.shape[1]):
        forward = forward * area_scale(rows, weights[:, ms.AREA], big_wi, big_wo).unsqueeze(-1)
    f = eval_stack([layer_batch(lobe[:, k]) for k in range(rows.shape[1])], big_wi, big_wo) + forward
    same = ((big_wi[..., 2] > 0) == (big_wo[..., 2] > 0)).unsqueeze(-1)
    lambert = torch.where(same, weights[:, None, ms.W2R], weights[:, None, ms.W2T]) / math.pi
    return ((f + lambert) * big_wo[..., 2:].abs()).reshape(*wi.shape[:2], wo.shape[1], 3)


@dataclasses.dataclass(frozen=True)
class Loss:
    """What ``lobe_loss`` weighs. ``floor``: added to each configuration's mean multiple scattering, which divides
    its loss; ``energy_weight``: the weight of the energy term; ``scaled``: the lobe term compares the prediction
    scaled, per wi and channel, to the Monte Carlo's energy there (``scaled_to``), i.e. the lobe's
    shape as the add-on renders it for stacks that take the energy fraction, whose energy scale gives each view its
    energy (``addon.bake.spongecake.fraction_limit``; by reciprocity the light's direction here, wo being uniform
    over the sphere); the energy term then keeps the lobes' own energy, which stacks over a substrate render."""
    floor: float = ENERGY_FLOOR
    energy_weight: float = ENERGY_WEIGHT
    scaled: bool = False


def lobe_loss(net, data: dict, index, rng=None, wi_per_step: int | None = None, loss: Loss = Loss()) -> torch.Tensor:
    """MAE of f |cos wo| per configuration, plus ``loss.energy_weight`` times the MAE of the energy each wi sends back
    and through (f |cos wo| averaged over the wo of each hemisphere), both relative to that configuration's mean
    multiple scattering (over all its pairs) plus ``loss.floor``. The energy term is there because an MAE fit of the
    lobe alone is the median, which ignores the narrow peaks of low-roughness flakes' multiple scattering (a few
    very large Monte Carlo values) and so under-predicts their energy; the error that matters is relative to each
    lobe, and the floor keeps configurations whose multiple scattering is negligible (mostly Monte Carlo noise)
    from dominating.
    With ``rng``, the batch is augmented by the model's exact symmetries (``augment``) and, with ``wi_per_step``,
    each configuration keeps that many of its wi, drawn at random (``some_wi``): an unbiased estimate of the loss
    at a fraction of the cost, every wi's energy term still exact."""
    batch = {k: data[k][index] for k in ("rows", "wi", "wo", "ms")}
    norm = target(batch).mean(dim=(1, 2, 3)) + loss.floor
    if rng is not None:
        batch = augment(batch, rng)
        if wi_per_step:
            batch = some_wi(batch, wi_per_step, rng)
    return batch_loss(net, batch, norm, loss)


def batch_loss(net, batch: dict, norm: torch.Tensor, loss: Loss = Loss()) -> torch.Tensor:
    """``lobe_loss`` of a prepared batch, each configuration's loss divided by its ``norm``."""
    truth = target(batch)
    predicted = predicted_lobe(net, *tensors(batch))
    shaped = scaled_to(predicted, truth) if loss.scaled else predicted
    lobe = (shaped - truth).abs().mean(dim=(1, 2, 3))
    down = torch.as_tensor(batch["wo"][:, None, :, 2:] < 0, device=DEVICE)
    energy = sum(((predicted - truth) * side).mean(dim=2).abs().mean(dim=(1, 2)) for side in (down, ~down))
    return ((lobe + loss.energy_weight * energy) / norm).mean()


def scaled_to(predicted: torch.Tensor, truth: torch.Tensor) -> torch.Tensor:
    """``predicted`` (B, n_wi, n_wo, 3) scaled per wi and channel to ``truth``'s energy (the mean over wo, uniform
    over the sphere), by at most the add-on's energy scale's ``MAX_SCALE``."""
    energy = predicted.mean(dim=2, keepdim=True)
    scale = (truth.mean(dim=2, keepdim=True) / energy.clamp_min(1e-12)).clamp(max=ms.MAX_SCALE)
    return predicted * scale


def some_wi(batch: dict, count: int, rng: np.random.Generator) -> dict:
    """The batch with ``count`` of each configuration's wi (and their lobes), drawn without replacement."""
    n, n_wi = batch["wi"].shape[:2]
    pick = rng.permuted(np.tile(np.arange(n_wi), (n, 1)), axis=1)[:, :min(count, n_wi)]
    return {**batch, "wi": np.take_along_axis(batch["wi"], pick[:, :, None], axis=1),
            "ms": np.take_along_axis(batch["ms"], pick[:, :, None, None], axis=1)}


def augment(batch: dict, rng: np.random.Generator) -> dict:
    """Exact symmetries of SpongeCake: the RGB channels are independent random-walk experiments over the same
    paths (permute albedo, f0 and the lobe together), and rotating or mirroring every orientation and direction
    about the normal changes nothing."""
    rows = batch["rows"].copy()
    n = len(rows)
    perm = rng.permuted(np.tile(np.arange(3), (n, 1)), axis=1)
    for channels in (layer_rows.ALBEDO, layer_rows.F0):
        rows[:, :, channels] = np.take_along_axis(rows[:, :, channels], perm[:, None, :], axis=2)
    angle = rng.uniform(0.0, 2.0 * np.pi, n)
    c, s = np.cos(angle), np.sin(angle)
    mirror = np.where(rng.random(n) < 0.5, -1.0, 1.0)
    turn = np.zeros((n, 3, 3))
    turn[:, 0, 0], turn[:, 0, 1], turn[:, 1, 0], turn[:, 1, 1], turn[:, 2, 2] = c, -s * mirror, s, c * mirror, 1.0

    def rotate(v):
        return np.einsum("nij,n...j->n...i", turn, v)

    rows[:, :, layer_rows.ORIENTATION] = rotate(rows[:, :, layer_rows.ORIENTATION])
    return {"rows": rows, "wi": rotate(batch["wi"]), "wo": rotate(batch["wo"]),
            "ms": np.take_along_axis(batch["ms"], perm[:, None, None, :], axis=3)}


def target(batch: dict) -> torch.Tensor:
    return torch.as_tensor(batch["ms"] * np.abs(batch["wo"][:, None, :, 2:]), dtype=PRECISION, device=DEVICE)


def tensors(batch: dict):
    return tuple(torch.as_tensor(batch[k], dtype=PRECISION, device=DEVICE) for k in ("rows", "wi", "wo"))


# ------------------------------------------------------------------------------------------ evaluation

def lobe_errors(net, data: dict) -> dict:
    """``addon.bake.validation.lobe_errors`` for the network being trained (torch forward pass)."""
    with torch.no_grad():
        predicted = predicted_lobe(net, *tensors(data)).cpu().numpy()
    return validation.lobe_errors(data, predicted)


# ------------------------------------------------------------------------------------------- training

def cosine_step(opt, loss, base_rate: float, frac: float) -> None:
    """One optimiser step on ``loss`` at the learning rate of cosine decay from ``base_rate``, ``frac`` of the way
    through the time budget (to 1e-5 at its end)."""
    for group in opt.param_groups:
        group["lr"] = base_rate * 0.5 * (1.0 + math.cos(math.pi * min(1.0, frac))) + 1e-5
    opt.zero_grad()
    loss.backward()
    opt.step()


def split(n_configs: int) -> tuple[np.ndarray, np.ndarray]:
    """The configurations held out for split validation (10%, at least one) and those trained on: ``SPLIT_SEED``'s
    permutation, the same for every run on a dataset of this size."""
    order = np.random.default_rng(SPLIT_SEED).permutation(n_configs)
    n_val = max(1, n_configs // 10)
    return order[:n_val], order[n_val:]


def train(data: dict, n_layers: int, minutes: float, seed: int = 0, batch: int = 32, init: mlp.MLP | None = None,
          log=print, area: bool = False, hidden: tuple = HIDDEN, wi_per_step: int | None = None,
          loss: Loss = Loss(), learning_rate: float = LEARNING_RATE):
    """Train for ``minutes``, from ``make_network``'s start or, with ``init``, from an exported network
    (``warm_start``); returns the network at its best split-validation loss (checked every few seconds) and what
    happened. ``area``: the form with the area exponents (module docstring); ``hidden``: the hidden layers'
    widths (a warm start takes its network's); ``wi_per_step`` and ``loss``: ``lobe_loss``'s; ``learning_rate``:
    where the cosine decay starts (a warm start may start lower, to keep what its network learned). ``seed`` sets
    the start and the batches; the split into training and validation configurations is ``SPLIT_SEED``'s for every
    seed, so that runs compare on one split."""
    torch.manual_seed(seed)
    rng = np.random.default_rng(seed)
    val, train_idx = split(len(data["rows"]))
    net = make_network(n_layers, area, hidden if init is None else init.hidden)
    if init is not None:
        warm_start(net, init)
    run = optimise(net, train_idx, lambda index: lobe_loss(net, data, index, rng, wi_per_step, loss),
                   lambda: lobe_loss(net, data, val, loss=loss).item(), minutes, batch, learning_rate, rng,
                   lambda text: log(f"  {n_layers} layer(s) {text}", flush=True))
    return net, {"seed": seed, **run, "batch": batch, "device": str(DEVICE), "wi_per_step": wi_per_step,
                 "energy_floor": loss.floor, "energy_weight": loss.energy_weight, "scaled_loss": loss.scaled,
                 "learning_rate": learning_rate, "precision": str(PRECISION).removeprefix("torch."),
                 "train_configs": int(len(train_idx)), "split_validation_configs": int(len(val)), "val_index": val}


def optimise(net, train_idx: np.ndarray, step_loss, check_loss, minutes: float, batch: int, learning_rate: float,
             rng: np.random.Generator, log) -> dict:
    """AdamW on ``net`` for ``minutes``: epochs of shuffled mini-batches of ``train_idx`` (``step_loss(index)``),
    the learning rate in cosine decay from ``learning_rate``, ``check_loss()`` at the start and every few seconds;
    ``net`` ends at the state of its best check. Returns what happened (epochs, steps, the best check's step, seconds)."""
    opt = torch.optim.AdamW(net.parameters(), lr=learning_rate, weight_decay=WEIGHT_DECAY)
    start, step, epoch, last_check, last_log = time.time(), 0, 0, -math.inf, -math.inf
    with torch.no_grad():
        best = (check_loss(), {k: v.clone() for k, v in net.state_dict().items()}, 0)  # a warm start may stay best
    budget = minutes * 60.0
    while time.time() - start < budget:
        epoch += 1
        shuffled = rng.permutation(train_idx)
        for i in range(0, len(shuffled), batch):
            step_loss_value = step_loss(shuffled[i:i + batch])
            cosine_step(opt, step_loss_value, learning_rate, (time.time() - start) / budget)
            step += 1
        if time.time() - last_check > min(5.0, budget / 20):
            last_check = time.time()
            with torch.no_grad():
                check = check_loss()
            if check < best[0]:
                best = (check, {k: v.clone() for k, v in net.state_dict().items()}, step)
            if time.time() - last_log > 30.0:
                last_log = time.time()
                log(f"epoch {epoch} step {step}: train loss {step_loss_value.item():.3e}, validation loss "
                    f"{check:.3e} (best {best[0]:.3e})  ({time.time() - start:.0f} s)")
    net.load_state_dict(best[1])
    return {"epochs": epoch, "steps": step, "best_step": best[2], "seconds": round(time.time() - start, 1)}


def record_held_out(path: Path, held_out: Path, training_form: bool = False) -> dict:
    """Score the exported weights file on the held-out set exactly as the add-on runs it (numpy, float32
    weights, the viewer-side choice of prediction) and record the result in its manifest; with ``training_form``,
    as training scores it (``predicted_lobe``: torch, the same float32 weights, the prediction from above for every
    wo). The manifest's ``held_out_scored_by`` says which."""
    mlp.load.cache_clear()
    shipped = mlp.load(path)
    n_layers = shipped.manifest["layers"]
    data = dataset.load(held_out, n_layers)
    if training_form:
        net = make_network(n_layers, shipped.weights[-1].shape[1] > outputs(n_layers), shipped.hidden)
        warm_start(net, shipped)
        scores = lobe_errors(net, data)
    else:
        scores = validation.lobe_errors(data, validation.predicted_lobes(data, shipped))
    manifest = {**shipped.manifest, "held_out_validation": {k: v for k, v in scores.items() if k != "per_config"},
                "held_out_per_config": scores["per_config"],
                "held_out_scored_by": "training form" if training_form else "add-on"}
    mlp.save(path, shipped.weights, shipped.biases, manifest)
    mlp.load.cache_clear()
    return manifest


def averaged(nets: list) -> tuple[list, list]:
    """Weights and biases of one MLP whose output is the mean of ``nets``' outputs (an ensemble; the same inputs,
    depth and activation): their hidden units side by side, each member's layers in a block of their own, and the
    last layer's weights stacked and divided by the count."""
    weights = [np.concatenate([n.weights[0] for n in nets], axis=1)]
    for i in range(1, len(nets[0].weights) - 1):
        weights.append(_block_diagonal([n.weights[i] for n in nets]))
    weights.append(np.concatenate([n.weights[-1] for n in nets], axis=0) / len(nets))
    biases = [np.concatenate([n.biases[i] for n in nets]) for i in range(len(nets[0].biases) - 1)]
    biases.append(np.mean([n.biases[-1] for n in nets], axis=0))
    return weights, biases


def _block_diagonal(blocks: list) -> np.ndarray:
    out = np.zeros((sum(b.shape[0] for b in blocks), sum(b.shape[1] for b in blocks)))
    r = c = 0
    for b in blocks:
        out[r:r + b.shape[0], c:c + b.shape[1]] = b
        r, c = r + b.shape[0], c + b.shape[1]
    return out


def ensemble(nets: list, member_keys: tuple) -> tuple[list, list, dict]:
    """The weights, biases and manifest of the network whose output is the mean of ``nets``' (``averaged``): the
    first member's manifest less what differs per member (``member_keys`` and the held-out details, listed per
    member under ``ensemble_of``), with the members' summed training time. Members must share their outputs."""
    if len({n.weights[-1].shape[1] for n in nets}) > 1:
        raise ValueError("the members of an ensemble must have the same outputs (the same form), these have "
                         + ", ".join(str(n.weights[-1].shape[1]) for n in nets))
    weights, biases = averaged(nets)
    per_member = ("held_out_per_config", "held_out_scored_by")
    manifest = {**{k: v for k, v in nets[0].manifest.items() if k not in member_keys + per_member},
                "hidden": list(mlp.hidden_widths(weights)),
                "ensemble_of": [{k: n.manifest.get(k) for k in member_keys} for n in nets],
                "training_seconds": round(sum(n.manifest.get("training_seconds", 0.0) for n in nets), 1),
                "date": datetime.date.today().isoformat(), "code_version": code_version()}
    return weights, biases, manifest


MEMBER_KEYS = ("seed", "epochs", "steps", "best_step", "training_seconds", "split_validation", "held_out_validation",
               "warm_started_from", "date", "code_version")  # what differs between an ensemble's members


def export_ensemble(folders: list, n_layers: int, out: Path, held_out: Path | None, log=print) -> dict:
    """The mean of the lobe networks for ``n_layers`` in ``folders`` (trained with different ``--seed``s on the
    same data, split and form: runs differ more than the held-out set resolves, and their mean varies less) as one
    network in ``out``, scored on the held-out set as the add-on runs it."""
    name = ms.weights_path(n_layers).name
    weights, biases, manifest = ensemble([mlp.load(Path(f) / name) for f in folders], MEMBER_KEYS)
    path = Path(out) / name
    path.parent.mkdir(parents=True, exist_ok=True)
    mlp.save(path, weights, biases, manifest)
    if held_out is not None and (Path(held_out) / f"layers{n_layers}").exists():
        manifest = record_held_out(path, held_out)
    log(f"wrote {path}: the mean of {len(folders)} networks: " + json.dumps(manifest.get("held_out_validation")))
    return manifest


def code_version() -> str:
    root = Path(__file__).resolve().parents[1]
    try:
        rev = subprocess.run(["git", "rev-parse", "--short", "HEAD"], cwd=root, capture_output=True, text=True,
                             check=True).stdout.strip()
        dirty = subprocess.run(["git", "status", "--porcelain", "--", "training", "addon/bake",
                                ":(exclude)addon/bake/weights"], cwd=root,
                               capture_output=True, text=True, check=True).stdout.strip()
        return rev + ("+local changes" if dirty else "")
    except (OSError, subprocess.CalledProcessError):  # a copy without git (a lent GPU machine): as its caller says
        return os.environ.get("LAMINA_CODE_VERSION", "unknown")


def export(net, info: dict, data: dict, n_layers: int, out: Path, held_out: Path | None, log=print) -> dict:
    net.eval()
    metas = data["meta"]
    val = {k: data[k][info["val_index"]] for k in validation.ARRAYS if k in data}
    split = {k: v for k, v in lobe_errors(net, val).items() if k != "per_config"}
    manifest = {
        "model": "spongecake multiple scattering", "layers": n_layers, "inputs": n_layers * ms.FEATURES,
        "hidden": [m.weight.shape[0] for m in net if isinstance(m, torch.nn.Linear)][:-1], "activation": "silu", "outputs": int(net[-1].bias.shape[0]),
        "area_exponents": int(net[-1].bias.shape[0]) > outputs(n_layers),
        "training_configs": info["train_configs"], "pairs_per_config": int(data["ms"].shape[1] * data["ms"].shape[2]),
        "paths_per_wi": metas[0]["paths"], "max_depth": metas[0]["max_depth"], "dataset_seed": metas[0]["seed"],
        "dataset_version": metas[0]["version"], "epochs": info["epochs"], "steps": info["steps"], "best_step": info["best_step"],
        "batch": info["batch"], "device": info["device"], "seed": info["seed"], "split_seed": SPLIT_SEED,
        "wi_per_step": info["wi_per_step"], "energy_floor": info["energy_floor"], "energy_weight": info["energy_weight"],
        "scaled_loss": info["scaled_loss"], "learning_rate": info["learning_rate"], "precision": info["precision"],
        "dataset_worker_seconds": round(sum(m.get("seconds", 0.0) for m in metas)),
        "training_seconds": info["seconds"], "split_validation": split, "dataset_noise": dataset.noise(data),
        "date": datetime.date.today().isoformat(), "code_version": code_version(),
    }
    if info.get("init"):
        manifest["warm_started_from"] = info["init"]
    if info.get("distilled_from"):  # ``training.distill``: trained towards per-configuration fits
        manifest["distilled_from"] = info["distilled_from"]
    path = Path(out) / ms.weights_path(n_layers).name
    exported = to_mlp(net, manifest)
    mlp.save(path, exported.weights, exported.biases, manifest)
    if held_out is not None and (held_out / f"layers{n_layers}").exists():
        record_held_out(path, held_out)
        manifest = mlp.load(path).manifest
    log(f"wrote {path}: " + json.dumps({k: manifest[k] for k in ("training_configs", "epochs", "split_validation")}))
    return manifest


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(prog="python -m training.train", description=__doc__.split("\n\n")[0])
    ap.add_argument("--data", type=Path, default=dataset.DEFAULT_CACHE)
    ap.add_argument("--layers", type=int, nargs="+", default=[1, 2], choices=[1, 2, 3, 4],
                    help="layer counts (3 and 4: --rescore only, grouped through the two-layer network)")
    ap.add_argument("--minutes", type=float, default=20.0, help="training time per network")
    ap.add_argument("--out", type=Path, required=True, help="folder for the .npz weights (addon/bake/weights ships)")
    ap.add_argument("--validation", type=Path, default=VALIDATION_SET)
    ap.add_argument("--threads", type=int, default=2)
    ap.add_argument("--seed", type=int, default=0,
                    help=f"the network's start and batches (the split is the same for every seed: {SPLIT_SEED})")
    ap.add_argument("--device", default="cpu", help="torch device to train on (cuda where a GPU is lent)")
    ap.add_argument("--float32", action="store_true",
                    help="train in float32 (on this CPU about 1.8 times the steps per second of float64)")
    ap.add_argument("--batch", type=int, default=32, help="configurations per mini-batch")
    ap.add_argument("--init", type=Path, help="folder of exported weights to go on training from (warm start; a "
                    "network without the forward lobe gets its outputs added), recorded in the manifest")
    ap.add_argument("--area", action="store_true",
                    help="scale the forward lobe by the layers' projected areas to a predicted power (one more "
                         "output per layer)")
    ap.add_argument("--hidden", type=int, nargs="+", default=list(HIDDEN),
                    help="hidden layers' widths of a network trained from scratch (--init takes its network's)")
    ap.add_argument("--wi-per-step", type=int, help="train each step on this many of a configuration's wi, drawn "
                    "at random (all of them if not given): more steps in the same time")
    ap.add_argument("--energy-floor", type=float, default=ENERGY_FLOOR,
                    help="added to each configuration's mean multiple scattering in the loss's denominator")
    ap.add_argument("--energy-weight", type=float, default=ENERGY_WEIGHT, help="the loss's energy term's weight")
    ap.add_argument("--learning-rate", type=float, default=LEARNING_RATE,
                    help="the cosine decay's starting rate (lower keeps more of a warm start's network)")
    ap.add_argument("--scaled-loss", action="store_true",
                    help="compare the lobes' shape at the Monte Carlo's energy per wi, as the energy scale renders them "
                         "(Loss.scaled)")
    ap.add_argument("--quick", action="store_true", help="a few seconds of training (tests)")
    ap.add_argument("--ensemble", type=Path, nargs="+", metavar="FOLDER",
                    help="write to --out the mean of the networks in these folders (``averaged``), scored, and stop")
    ap.add_argument("--rescore", action="store_true",
                    help="only re-score the weights in --out on --validation and record it in their manifests")
    ap.add_argument("--training-form", action="store_true",
                    help="with --rescore: score as training does (torch, the prediction from above for every wo)")
    a = ap.parse_args(argv)
    torch.set_num_threads(a.threads)
    global DEVICE, PRECISION
    DEVICE = torch.device(a.device)
    PRECISION = torch.float32 if a.float32 else torch.float64
    if a.ensemble:
        for n_layers in a.layers:
            export_ensemble(a.ensemble, n_layers, a.out, a.validation)
        return 0
    if a.rescore:
        for n_layers in a.layers:
            if n_layers > ms.NETWORK_LAYERS:  # no network of its own: score the grouped prediction, record nothing
                scores = validation.lobe_errors(validation.load_shards(a.validation, n_layers))
                print(json.dumps({"layers": n_layers, "grouped": True,
                                  **{k: v for k, v in scores.items() if k != "per_config"}}))
                continue
            scores = record_held_out(Path(a.out) / ms.weights_path(n_layers).name, a.validation, a.training_form)
            print(json.dumps({"layers": n_layers, **scores["held_out_validation"]}))
        return 0
    if max(a.layers) > ms.NETWORK_LAYERS:
        print(f"networks are trained for 1 or {ms.NETWORK_LAYERS} layers; deeper stacks are grouped (score them with "
              f"--rescore)", file=sys.stderr)
        return 2
    for n_layers in a.layers:
        data = dataset.load(a.data, n_layers)
        minutes = 0.05 if a.quick else a.minutes
        print(f"training the {n_layers}-layer network on {len(data['rows'])} configurations for {minutes} min",
              flush=True)
        init = mlp.load(Path(a.init) / ms.weights_path(n_layers).name) if a.init else None
        net, info = train(data, n_layers, minutes, seed=a.seed, batch=4 if a.quick else a.batch, init=init,
                          area=a.area, hidden=tuple(a.hidden), wi_per_step=a.wi_per_step,
                          loss=Loss(a.energy_floor, a.energy_weight, a.scaled_loss), learning_rate=a.learning_rate)
        if init is not None:
            info["init"] = {k: init.manifest.get(k) for k in ("training_configs", "steps", "training_seconds", "date",
                                                               "code_version", "held_out_validation", "outputs")}
        export(net, info, data, n_layers, a.out, a.validation)
    return 0


if __name__ == "__main__":
    sys.exit(main())
