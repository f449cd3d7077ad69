"""Score the shipped multiple-scattering networks against Monte Carlo data (numpy only; no torch).

Data come in the dataset's shard format (``training/dataset.py``): folders ``layers1/``, ``layers2/`` of
``shard*.npz`` with ``rows``, ``wi``, ``wo``, ``ms`` (order >= 2 of f, no cosine) and ``ms_half_diff``.
"""
from __future__ import annotations

import json
from pathlib import Path

import numpy as np

from . import layer_rows
from ..reference.frames import spherical
from ..reference.spongecake import (energy_at, energy_tables, eval_multiple, ground_truth_albedo, leftover,
                                    lobes_albedo, single_leftover)
from .spongecake import energy_grid, fraction_rows, network, predict_with

ARRAYS = ("rows", "wi", "wo", "ms", "ms_half_diff", "ss")
ENERGY_ARRAYS = ("rows", "wi", "unscattered", "single", "multiple")  # ``training.energy_train``'s tallies


def load_shards(folder, n_layers: int) -> dict:
    """All shards of one layer count concatenated (the arrays above, plus ``meta``: one dict per shard)."""
    files = sorted((Path(folder) / f"layers{n_layers}").glob("shard*.npz"))
    if not files:
        raise FileNotFoundError(f"no {n_layers}-layer shards in {folder}: run python -m training.dataset first")
    parts = []
    for f in files:
        with np.load(f) as data:
            parts.append({k: data[k] for k in (*ARRAYS, "meta")})
    out = {k: np.concatenate([p[k] for p in parts]) for k in ARRAYS}
    out["meta"] = [json.loads(str(p["meta"])) for p in parts]
    return out


def predicted_lobes(data: dict, net=None, energy: bool = True) -> np.ndarray:
    """The network's multiple-scattering lobe f_ms |cos wo| at every stored pair, (C, n_wi, n_wo, 3), exactly as
    the add-on evaluates it (``eval_multiple``: the shipped network with its energy scale), or without the energy
    scale (``energy`` False, or a given ``net``, an ``mlp.MLP``)."""
    out = np.zeros(data["ms"].shape)
    for c, rows in enumerate(data["rows"]):
        params = layer_rows.params_from_rows(rows)
        wi, wo = data["wi"][c].astype(float), data["wo"][c].astype(float)
        big_wi, big_wo = np.repeat(wi, len(wo), axis=0), np.tile(wo, (len(wi), 1))
        prediction = None if net is None and energy else predict_with(net or network(len(rows)), params)
        f = eval_multiple(params, big_wi, big_wo, prediction) * np.abs(big_wo[:, 2:])
        out[c] = f.reshape(out[c].shape)
    return out


def scored_lobes(data: dict):
    """The Monte Carlo lobe f_ms |cos wo| (C, n_wi, n_wo, 3), its sum per configuration, and which configurations
    are scored: those with at least 1e-3 of the largest sum."""
    truth = data["ms"] * np.abs(data["wo"][:, None, :, 2:])
    total = truth.sum(axis=(1, 2, 3))
    return truth, total, total > 1e-3 * total.max()


def standard_error(values: np.ndarray) -> float:
    """The standard error of ``values``' mean: their sample deviation over √count (0 for fewer than two)."""
    return float(np.std(values, ddof=1) / np.sqrt(len(values))) if len(values) > 1 else 0.0


def monte_carlo_noise(data: dict) -> np.ndarray:
    """Per configuration, the Monte Carlo lobe's own relative L1 noise: the standard errors of its stored pairs
    (|a - b| / 2 of the walk's two halves, ``training.dataset``) times |cos wo|, summed, over the lobe's sum."""
    _, total, _ = scored_lobes(data)
    return (np.abs(data["ms_half_diff"]) * np.abs(data["wo"][:, None, :, 2:])).sum(axis=(1, 2, 3)) / np.maximum(
        total, 1e-12)


def lobe_errors(data: dict, predicted: np.ndarray | None = None) -> dict:
    """Per configuration, the relative L1 error of the predicted lobe (f |cos wo| summed over the stored pairs)
    against Monte Carlo, its relative energy error, and the Monte Carlo noise's own relative L1 for scale; the mean
    lobe error's standard error (the configurations' spread over √count: how far the set's mean may lie from the
    mean over all stacks the dataset draws).
    Configurations with less than 1e-3 of the largest multiple-scattering energy are left out of the means."""
    pred = predicted_lobes(data) if predicted is None else predicted
    truth, total, keep = scored_lobes(data)
    safe = np.maximum(total, 1e-12)
    rel = np.abs(pred - truth).sum(axis=(1, 2, 3)) / safe
    energy = (pred.sum(axis=(1, 2, 3)) - total) / safe
    out = {"configs": int(keep.sum()), "mean_relative_lobe_error": float(rel[keep].mean()),
           "standard_error_of_mean": standard_error(rel[keep]),
           "median_relative_lobe_error": float(np.median(rel[keep])),
           "worst_relative_lobe_error": float(rel[keep].max()),
           "mean_relative_energy_error": float(np.abs(energy[keep]).mean())}
    if "ms_half_diff" in data:  # a training pack (training.dataset.pack) leaves it out
        out["mean_monte_carlo_noise"] = float(monte_carlo_noise(data)[keep].mean())
    return {**out, "per_config": np.where(keep, rel, np.nan).tolist()}


ALBEDO_PATHS = 200000  # random-walk paths per view of ``returned_light`` (its noise, ``walk_noise``: 0.5–0.7%)
NOISE_SEED_OFFSET = 1_000_003  # the second half-walk's seed, past any configuration index


def returned_light(data: dict, paths: int = ALBEDO_PATHS) -> list[dict]:
    """The light multiple scattering returns at each scored configuration's stored views wi above the stack (its
    multiple-scattering albedo, (n, 3)): an independent random walk's (orders >= 2, ``ground_truth_albedo``, the
    mean of two half-walks seeded by the configuration's index and that plus ``NOISE_SEED_OFFSET``) beside the
    model's, the network's lobes' albedo (``lobes_albedo``) times the energy scale there (``scaled``) and without it
    (``lobes``). ``walk_noise`` is the walk's own relative L1 error, estimated from its halves: for two independent
    estimates a, b of the same mean, E|(a + b)/2 − mean| = E|a − b| / 2 (normal noise), so Σ|a − b| / Σ(a + b). The
    lobe set's energy error sums f |cos wo| over the stored pairs and so follows the lobes' shape; this is the
    energy itself."""
    out = []
    for c in np.flatnonzero(scored_lobes(data)[2]):
        params = layer_rows.params_from_rows(data["rows"][c])
        wi = data["wi"][c].astype(float)
        wi = wi[wi[:, 2] > 0]
        halves = [ground_truth_albedo(params, wi, n_paths=max(1, paths // 2), seed=int(c) + offset)[2]
                  for offset in (0, NOISE_SEED_OFFSET)]
        lobes = lobes_albedo(params, wi)
        out.append({"config": int(c), "walk": 0.5 * (halves[0] + halves[1]), "lobes": lobes,
                    "scaled": lobes * energy_at(energy_tables(params)[0], wi),
                    "walk_noise": float(np.abs(halves[0] - halves[1]).sum()
                                        / max(float((halves[0] + halves[1]).sum()), 1e-12))})
    return out


def returned_light_errors(light: list[dict], energy: bool = True) -> np.ndarray:
    """Per configuration of ``returned_light``, the relative L1 error of the model's albedo (with the energy scale,
    or without it) against the walk's, over the views and channels."""
    key = "scaled" if energy else "lobes"
    return np.array([np.abs(r[key] - r["walk"]).sum() / max(float(r["walk"].sum()), 1e-12) for r in light])


# ------------------------------------------------------------------------------ the energy fraction network

def load_energy_set(path, n_layers: int) -> dict:
    """One layer count of an energy held-out file (``training.energy_train --validation-set``): ``ENERGY_ARRAYS``."""
    with np.load(path) as f:
        return {k: f[f"layers{n_layers}_{k}"] for k in ENERGY_ARRAYS}


def energy_samples(data: dict, left: np.ndarray | None = None) -> dict:
    """Flat (stack, wi, channel) ``left`` (the walk's own, 1 − T_δ − E_1, unless given), the multiple-scattering
    energy (``energy``, the walk's orders ≥ 2) and each sample's stack (``config``)."""
    n_c, n_wi = data["wi"].shape[:2]
    if left is None:
        left = 1.0 - data["unscattered"] - data["single"]
    return {"left": np.asarray(left).reshape(-1), "energy": data["multiple"].reshape(-1),
            "config": np.repeat(np.arange(n_c), n_wi * 3)}


def fraction_errors(q: np.ndarray, samples: dict) -> np.ndarray:
    """Per stack, the relative energy error |Σ q left − Σ E_ms| / Σ E_ms over its wi and channels (as ``lobe_errors``
    scores a lobe's energy); stacks with less than 1e-3 of the largest energy are left out (NaN)."""
    return relative_energy_errors(q * samples["left"], samples)


def relative_energy_errors(energy: np.ndarray, samples: dict) -> np.ndarray:
    """``fraction_errors`` of predicted multiple-scattering energies (flat, in ``samples``' order)."""
    n = samples["config"].max() + 1
    predicted = np.bincount(samples["config"], weights=energy, minlength=n)
    truth = np.bincount(samples["config"], weights=samples["energy"], minlength=n)
    return np.where(truth > 1e-3 * truth.max(), np.abs(predicted - truth) / np.maximum(truth, 1e-300), np.nan)


def per_view_energy_errors(energy: np.ndarray, samples: dict) -> np.ndarray:
    """Per stack, Σ |predicted − E_ms| / Σ E_ms over its wi and channels of predicted multiple-scattering energies
    (flat, in ``samples``' order): each view's own error, where ``relative_energy_errors`` lets views' errors of
    opposite signs cancel; stacks left out as there (NaN)."""
    n = samples["config"].max() + 1
    miss = np.bincount(samples["config"], weights=np.abs(energy - samples["energy"]), minlength=n)
    truth = np.bincount(samples["config"], weights=samples["energy"], minlength=n)
    return np.where(truth > 1e-3 * truth.max(), miss / np.maximum(truth, 1e-300), np.nan)


def error_summary(errors: np.ndarray) -> dict:
    kept = errors[~np.isnan(errors)]
    return {"configs": int(len(kept)), "mean_relative_energy_error": float(kept.mean()),
            "median_relative_energy_error": float(np.median(kept)), "worst_relative_energy_error": float(kept.max())}


def energy_errors(path, n_layers: int, net=None) -> dict:
    """The energy network (shipped, or ``net``) on a held-out energy file as the add-on evaluates q (numpy), times
    left from the reference (``leftover``, the add-on's samples), against the walk's E_ms; with ``per_config`` and
    the mean of ``per_view_energy_errors``."""
    data = load_energy_set(path, n_layers)
    left = np.stack([leftover(layer_rows.params_from_rows(stack), wi) for stack, wi in zip(data["rows"], data["wi"])])
    q = fraction_rows(np.repeat(data["rows"], data["wi"].shape[1], axis=0), data["wi"].reshape(-1, 3), net)
    samples = energy_samples(data, left)
    errors = fraction_errors(q.reshape(-1), samples)
    per_view = per_view_energy_errors(q.reshape(-1) * samples["left"], samples)
    return {**error_summary(errors), "mean_per_view_energy_error": float(np.nanmean(per_view)),
            "per_config": [None if np.isnan(e) else float(e) for e in errors]}


def model_energy_errors(path, n_layers: int, fraction: bool = True) -> dict:
    """``energy_errors``' measure of the model's multiple-scattering energy as the reference evaluates it: at each
    held-out wi the shipped network's lobes' albedo towards wi times the energy scale there (``energy_grid`` at that
    one view, no table between views), with the energy fraction or, ``fraction`` False, without it (the lobes' own
    energy, at most what single scattering leaves, scaled towards all of that for stacks close to white:
    ``white_limit``). By reciprocity the light a view's lobes return is what the walk tallies for light from that
    direction."""
    data = load_energy_set(path, n_layers)
    energy = []
    for stack, wi in zip(data["rows"], data["wi"]):
        params = layer_rows.params_from_rows(stack)
        for w in wi:
            mu, phi = np.array([w[2]]), np.array([np.arctan2(w[1], w[0])])
            scale = energy_grid(params, single_leftover, lobes_albedo, mu, phi, fraction=fraction)[0, 0]
            energy.append(scale * lobes_albedo(params, spherical(mu, phi))[0])
    errors = relative_energy_errors(np.reshape(energy, -1), energy_samples(data))
    return {**error_summary(errors), "per_config": [None if np.isnan(e) else float(e) for e in errors]}
