"""How close the lobe form can come to the Monte Carlo data at all: W1 f_ss(params') + W2 / pi (the paper's) or
that plus the forward lobe f_ss(forward) (``--forward``; ``addon.bake.spongecake``), with every output optimised
for each held-out configuration on its own (no network), starting from the shipped network's
prediction. The gap between this bound and the network is what more data and training can win; what is left at the
bound is the lobe form's own (issue 15's goal of 25% mean lobe error is measured against it in docs/training.md).

    python -m training.lobe_bound            # both layer counts of the shipped held-out set, a few minutes
    python -m training.lobe_bound --halves   # one layer, as two identical halves through the two-layer form
    python -m training.lobe_bound --forward  # with the forward lobe (an HG layer's single scattering)
    python -m training.lobe_bound --forward --breakdown  # and where, by direction, each error lies
    python -m training.lobe_bound --area     # the forward lobe scaled by the layers' projected areas
    python -m training.lobe_bound --area --folds 3  # cross-validated over wi: each scored by a fit that never saw it
    python -m training.lobe_bound --area --fresh-wi 36  # fitted to a new walk at 36 other wi, scored at the stored ones

The loss is the score itself: the relative L1 error of f |cos wo| over each configuration's stored pairs
(``validation.lobe_errors``), optionally plus ``--energy`` times the relative error of its energy (the training
loss's balance), minimised by Adam with a cosine learning-rate decay.
"""
from __future__ import annotations

import argparse
import dataclasses
import json
import math
import sys
from multiprocessing import Pool
from pathlib import Path

import numpy as np
import torch

from addon.bake import layer_rows, validation
from addon.bake import spongecake as ms
from training import dataset, train


def best_lobes(data: dict, steps: int, rate: float, energy: float = 0.0, forward: bool = False,
               area: bool = False, folds: int = 1, view_linear: bool = False,
               fit_to: dict | None = None) -> np.ndarray:
    """f |cos wo| (C, n_wi, n_wo, 3) of the lobe form, with the forward lobe or without, with its outputs optimised
    per configuration (started from the shipped network's; the forward lobe's from ``train.FORWARD_START`` where that
    network has none); ``area`` (and so the forward lobe) adds one exponent per layer (``train.area_scale``), started
    from the shipped network's or ``train.AREA_START``. With ``folds`` > 1 the fit is cross-validated over the
    light's directions: each configuration's wi are dealt into ``folds`` groups (wi k into group k % folds), and each
    group's lobes come from the outputs fitted to the other groups' wi, so that the score says what the form reaches
    at directions it was not fitted to (``fold_of``). ``view_linear``: a richer form whose outputs follow the light's
    direction, linear in 1 - cos θi (``lobes_at``). ``fit_to``: other Monte Carlo data of the same configurations
    (``fresh_data``) that the outputs are fitted to instead, so that every stored pair is scored by lobes fitted to
    directions and paths it is not among."""
    if fit_to is not None and folds > 1:
        raise ValueError("fit to fresh data or cross-validate over the stored wi, not both")
    forward = forward or area
    rows = data["rows"]
    start = ms.network(rows.shape[1])(ms.features(rows.astype(np.float64)))
    plain, with_forward, with_area = ms.output_widths(rows.shape[1])
    if start.shape[1] == plain:
        start = np.concatenate([start, np.tile(train.FORWARD_START, (len(start), 1))], axis=1)
    if start.shape[1] == with_forward:
        start = np.concatenate([start, np.full((len(start), rows.shape[1]), train.AREA_START)], axis=1)
    width = with_area if area else with_forward if forward else plain
    start = start[:, :width]
    if view_linear:
        start = np.concatenate([start, np.zeros_like(start)], axis=1)
    out = np.zeros(data["ms"].shape)
    group = fold_of(data["wi"].shape[1], folds)
    for k in range(folds):
        fitted_to = fit_to if fit_to is not None else with_wi(data, group != k) if folds > 1 else data
        raw = best_outputs(fitted_to, start, steps, rate, energy, view_linear=view_linear)
        with torch.no_grad():
            out[:, group == k] = lobes_at(raw, *train.tensors(with_wi(data, group == k)), view_linear).cpu()
    return out


def lobes_at(raw: torch.Tensor, rows: torch.Tensor, wi: torch.Tensor, wo: torch.Tensor, view_linear: bool = False):
    """``train.predicted_lobe`` of the outputs ``raw`` (C, width), one set per configuration; with
    ``view_linear``, ``raw`` is (C, 2 width), a and b, and the outputs at each wi are a + b (1 - cos θi)."""
    if not view_linear:
        return train.predicted_lobe(lambda x: raw, rows, wi, wo)
    n, n_wi = wi.shape[:2]
    a, b = raw.repeat_interleave(n_wi, dim=0).chunk(2, dim=1)
    one_wi = wi.reshape(n * n_wi, 1, 3)
    lobes = train.predicted_lobe(lambda x: a + b * (1.0 - one_wi[:, 0, 2:]), rows.repeat_interleave(n_wi, dim=0),
                                 one_wi, wo.repeat_interleave(n_wi, dim=0))
    return lobes.reshape(n, n_wi, *lobes.shape[2:])


def fold_of(n_wi: int, folds: int) -> np.ndarray:
    """Which group each of ``n_wi`` stored wi falls in: wi k in group k % folds (the stored wi are stratified by
    elevation first, so each group spans the elevations)."""
    return np.arange(n_wi) % folds


def with_wi(data: dict, keep: np.ndarray) -> dict:
    """``data`` with only the wi ``keep`` says (and their lobes)."""
    return {**data, "wi": data["wi"][:, keep], "ms": data["ms"][:, keep]}


FRESH = dataset.Size(configs=0, n_wi=36, n_wo=128)  # ``fresh_data``'s directions and paths per wi (the dataset's)
FRESH_SEED = 2027  # not the training data's (0) nor the held-out set's (1001)
FRESH_CACHE = dataset.DEFAULT_CACHE.parent / "lobe-bound-fresh"


def fresh_data(data: dict, size: dataset.Size = FRESH, seed: int = FRESH_SEED, cache: Path = FRESH_CACHE,
               workers: int = 1) -> dict:
    """The configurations of ``data`` simulated anew by the dataset's walk (``dataset.simulate``) at ``size.n_wi``
    jittered-stratified wi and ``size.n_wo`` wo of their own, seeded by (seed, layer count, configuration): what
    the form's outputs fitted to them reach is that of the best outputs for the stack over all directions, the
    ones a network would ideally predict. One file per configuration in ``cache`` (resumable)."""
    n_layers = data["rows"].shape[1]
    folder = Path(cache) / f"layers{n_layers}-{size.n_wi}x{size.n_wo}x{size.paths}-seed{seed}"
    jobs = [(folder / f"config{c:04d}.npz", rows, size, seed, c) for c, rows in enumerate(data["rows"])]
    if workers > 1:
        with Pool(workers) as pool:
            list(pool.imap(_fresh_config, jobs))
    else:
        for job in jobs:
            _fresh_config(job)
    parts = []
    for path, rows, *_ in jobs:
        with np.load(path) as stored:
            if not np.array_equal(stored["rows"], rows):
                raise ValueError(f"{path} holds another stack: remove {folder}")
            parts.append({k: stored[k] for k in ("rows", "wi", "wo", "ms")})
    return {k: np.stack([p[k] for p in parts]) for k in parts[0]}


def _fresh_config(job) -> str:
    path, rows, size, seed, index = job

    def make():
        rng = np.random.default_rng(np.random.SeedSequence([seed, len(rows), index]))
        wi, wo = dataset.stratified_hemisphere(rng, size.n_wi), dataset.stratified_sphere(rng, size.n_wo)
        ms_, _, _ = dataset.simulate(rows, wi, wo, size, int(rng.integers(0, 2**31)))
        meta = {"seed": seed, "config": index, **dataclasses.asdict(size)}
        return {"rows": rows, "wi": wi, "wo": wo, "ms": ms_}, meta

    return dataset.write_once(path, make)


def best_outputs(data: dict, start: np.ndarray, steps: int, rate: float, energy: float = 0.0,
                 scaled: float = 0.0, view_linear: bool = False) -> torch.Tensor:
    """The network outputs (C, width) that minimise each configuration's score, started from ``start``: Adam with a
    cosine decay from ``rate``, on the relative L1 error of f |cos wo| (``validation.lobe_errors``), plus ``energy``
    times the relative error of its energy and ``scaled`` times the relative L1 error of the lobes scaled to the
    Monte Carlo's energy per wi and channel (``train.scaled_to``: the shape the energy scale renders);
    ``view_linear``: outputs that follow the light's direction (``lobes_at``)."""
    rows, wi, wo = train.tensors(data)
    truth = train.target(data)
    total = truth.sum(dim=(1, 2, 3)).clamp_min(1e-12)
    raw = torch.tensor(start, dtype=truth.dtype, device=truth.device, requires_grad=True)
    opt = torch.optim.Adam([raw], lr=rate)
    for step in range(steps):
        for group in opt.param_groups:
            group["lr"] = rate * 0.5 * (1.0 + math.cos(math.pi * step / steps)) + 1e-5
        predicted = lobes_at(raw, rows, wi, wo, view_linear)
        lobe = (predicted - truth).abs().sum(dim=(1, 2, 3)) / total
        gained = (predicted.sum(dim=(1, 2, 3)) - truth.sum(dim=(1, 2, 3))).abs() / total
        loss = lobe + energy * gained
        if scaled:
            loss = loss + scaled * (train.scaled_to(predicted, truth) - truth).abs().sum(dim=(1, 2, 3)) / total
        opt.zero_grad()
        loss.sum().backward()
        opt.step()
    return raw.detach()


CONE = 0.9  # cos 25.8°: the cones around the light's own direction and its mirror image in ``regions``
GRAZING = 0.2  # cos 78.5°: light this close to the surface is counted apart


def regions(data: dict) -> dict:
    """Each stored pair (C, n_wi, n_wo) in exactly one region, the first that holds it: ``forward`` (wo within the
    cone around the light's direction of travel, -wi), ``mirror`` (within the cone around wi's mirror image),
    ``grazing`` (light with cos θi below GRAZING), else ``reflection`` or ``transmission``."""
    wi, wo = data["wi"].astype(float)[:, :, None, :], data["wo"].astype(float)[:, None, :, :]
    forward = -(wi * wo).sum(-1) > CONE
    mirror = (wi * wo * np.array([-1.0, -1.0, 1.0])).sum(-1) > CONE
    grazing = np.broadcast_to(wi[..., 2] < GRAZING, forward.shape)
    above = np.broadcast_to(wo[..., 2] > 0.0, forward.shape)
    taken = forward | mirror | grazing
    return {"forward": forward, "mirror": mirror & ~forward, "grazing": grazing & ~(forward | mirror),
            "reflection": above & ~taken, "transmission": ~above & ~taken}


def error_by_region(data: dict, predicted: np.ndarray) -> dict:
    """The mean relative lobe error (``validation.lobe_errors``) split by ``regions``: for each, the mean over the
    scored configurations of the region's summed |predicted - truth| over the configuration's whole lobe (the parts
    add up to the mean error), and the share of the Monte Carlo lobe the region holds."""
    truth, total, keep = validation.scored_lobes(data)
    error = np.abs(predicted - truth).sum(-1)
    safe = np.maximum(total, 1e-12)
    out = {}
    for name, where in regions(data).items():
        out[name] = {"error": float(((error * where).sum(axis=(1, 2)) / safe)[keep].mean()),
                     "truth": float(((truth.sum(-1) * where).sum(axis=(1, 2)) / safe)[keep].mean())}
    return out


def scored(data: dict) -> dict:
    """The configurations ``validation.lobe_errors`` scores (its means leave the others out), alone."""
    keep = validation.scored_lobes(data)[2]
    return {k: v[keep] for k, v in data.items() if k != "meta"}


def halved(data: dict) -> dict:
    """One-layer configurations as the same layer cut in two identical halves (the same material): the two-layer
    lobe form, with an extra lobe per half, applies to them."""
    rows = np.repeat(data["rows"], 2, axis=1)
    rows[:, :, layer_rows.THICKNESS] *= 0.5
    return {**data, "rows": rows}


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(prog="python -m training.lobe_bound", description=__doc__.split("\n\n")[0])
    ap.add_argument("--validation", default=str(train.VALIDATION_SET))
    ap.add_argument("--steps", type=int, default=2000)
    ap.add_argument("--rate", type=float, default=0.02)
    ap.add_argument("--energy", type=float, default=0.0, help="weight of the energy error in the loss")
    ap.add_argument("--halves", action="store_true",
                    help="one layer only: the two-layer form on the layer cut in two halves (--validation's 1 layer)")
    ap.add_argument("--layers", type=int, nargs="+", default=[1, 2], choices=[1, 2])
    ap.add_argument("--forward", action="store_true",
                    help="with the forward lobe (an HG layer's single scattering; without it the paper's form)")
    ap.add_argument("--area", action="store_true",
                    help="the forward lobe (--forward implied) scaled by each layer's projected areas along wi and wo "
                         "to a power of its own (``train.area_scale``; the one-layer network's form since 2026-12-05)")
    ap.add_argument("--folds", type=int, default=1,
                    help="cross-validate over each configuration's wi: fit on all groups but one, score that one")
    ap.add_argument("--fresh-wi", type=int, default=0,
                    help="fit to a new walk of each configuration at this many other wi (a square number), score at "
                         "the stored pairs (``fresh_data``; cached, resumable)")
    ap.add_argument("--workers", type=int, default=1, help="processes for --fresh-wi's walks")
    ap.add_argument("--view-linear", action="store_true",
                    help="a richer form: the outputs linear in 1 - cos θi (two per output), to be cross-validated "
                         "(--folds) or fitted fresh (--fresh-wi)")
    ap.add_argument("--breakdown", action="store_true",
                    help="also split each mean lobe error by the directions it lies in (``regions``)")
    a = ap.parse_args(argv)
    torch.set_num_threads(1)
    for n_layers in (1,) if a.halves else a.layers:
        data = scored(validation.load_shards(a.validation, n_layers))
        form = halved(data) if a.halves else data
        fresh = None
        if a.fresh_wi:
            fresh = fresh_data(data, dataclasses.replace(FRESH, n_wi=a.fresh_wi), workers=a.workers)
            fresh = {**fresh, "rows": form["rows"]}
        for label, predicted in (("network", validation.predicted_lobes(form, energy=False)),
                                 ("bound", best_lobes(form, a.steps, a.rate, a.energy, a.forward, a.area,
                                                      a.folds, a.view_linear, fresh))):
            scores = validation.lobe_errors(data, predicted)
            by_region = {"regions": error_by_region(data, predicted)} if a.breakdown else {}
            print(json.dumps({"layers": n_layers, "halves": a.halves, "forward": a.forward or a.area, "area": a.area,
                              "lobes": label,
                              "steps": a.steps, "folds": a.folds, "fresh_wi": a.fresh_wi,
                              "view_linear": a.view_linear,
                              "energy_weight": a.energy,
                              **scores, **by_region}), flush=True)
    return 0


if __name__ == "__main__":
    sys.exit(main())
