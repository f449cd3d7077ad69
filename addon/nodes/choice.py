"""Which mapping a material renders with: analytic, fitted, or Auto (bpy-free).

``fit_for`` fits the material against the model's float64 reference (``fitted.fit``, one fit per ``VARIANTS``:
residual weighting and dictionary), cached by content (parameters, form, fitter version) in memory and on disk;
``fits_for`` makes every variant's fit at once, on one quadrature (``fitted.fit_variants``).
``choose`` measures the analytic mapping and each distinct fit on the comparison scenes at ``CHOICE_RESOLUTION`` (the
scenes and resolution ``make bench`` reports; a smaller furnace): the Fitted mapping is the closest fit, and Auto
keeps the analytic one unless the fitted one is lower by ``AUTO_MARGIN``.

A texture-driven or keyframed input (``driven``: ``fitted.Driven``, ``driven_over``) is tabulated at
``DRIVEN_VALUES`` values across its range (``fitted.fit_driven``). The choice is measured at the middle value, with
the fits of that value; the winning variant is then fitted at every value.
"""
from __future__ import annotations

import importlib
import json
import os
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from . import MAPPINGS, fittable, fitted, predicted_image

FITTER_VERSION = 7  # bump when fits change, so cached ones are not reused
CHOICE_RESOLUTION = 48
CHOICE_FURNACE_WIDTH = 12  # the furnace panorama's width (the bench's is 24: its prediction costs an albedo per pixel)
AUTO_MARGIN = 0.01  # Auto takes the fitted mapping only where it is lower by this much (absolute rel. RMSE)
BACKLIT_MIN_MEAN = 1e-3  # a scene whose reference mean is below this is not counted (e.g. backlit opaque stacks)
REFERENCE_ALBEDO_SAMPLES = 4096  # the reference's directional albedo per fitted view
SCENE_ALBEDO_SAMPLES = 1024  # per furnace pixel in the choice's scenes
DRIVEN_VALUES = 5  # tabulated values of a driven input (odd: the middle one is where the choice is measured)
_fits: dict[str, fitted.Fit] = {}


def cache_folder() -> Path:
    return Path(os.environ.get("LAMINA_CACHE", Path.home() / ".cache" / "lamina")) / "fits"


def fit_key(model_id: str, p, form: str, driven: fitted.Driven | None = None) -> str:
    """What a fit depends on: the parameters, the form, for node groups whether they have the Metallic BSDF (OSL
    always has ``metal``, so an OSL fit made under Blender 4.2 holds under 5.0), the fitter, a driven input's
    tabulated values (the input's own constant does not count then) and, with multiple scattering, what the
    reference's multiple scattering comes from (the bake module's ``ms_identity``)."""
    from .expr import NumpyBackend

    if driven is not None:
        p = at(model_id, p, driven, len(driven.values) // 2)
    metallic_node = NumpyBackend.metallic_node if form == "nodes" else None
    parts = [FITTER_VERSION, model_id, p.to_dict(), form, metallic_node, driven and driven.to_json()]
    if getattr(p, "multiple_scattering", False):
        parts.append(importlib.import_module(f"..bake.{model_id}", __package__).ms_identity(len(p.layers)))
    return __import__("hashlib").sha256(json.dumps(parts, sort_keys=True).encode()).hexdigest()[:24]


def driven_over(model_id: str, p, socket: str, lo: float, hi: float) -> fitted.Driven:
    """The driven input ``socket`` of ``p`` tabulated at ``DRIVEN_VALUES`` values from ``lo`` to ``hi`` (one value
    when they are equal), clamped to the parameter's range."""
    s = next(s for s in MAPPINGS[model_id].sockets(p) if s.name == socket)
    if s.kind not in ("float", "color"):
        raise ValueError(f"{socket}: a {s.kind} input cannot be tabulated (only float and colour inputs)")
    lo, hi = (float(np.clip(v, s.param.min, s.param.max)) for v in (lo, hi))
    count = DRIVEN_VALUES if hi > lo else 1
    return fitted.Driven(socket, s.kind, tuple(float(v) for v in np.linspace(lo, hi, count)))


def at(model_id: str, p, driven: fitted.Driven, j: int):
    """``p`` with the driven input at its j-th tabulated value."""
    mapping = MAPPINGS[model_id]
    return mapping.with_values(p, {**mapping.input_values(p), driven.socket: driven.value(j)})


def reference_of(model_id: str):
    return importlib.import_module(f"..reference.{model_id}", __package__)


@dataclass(frozen=True)
class Variant:
    """One of a material's fits: the residual weighting (``fitted.fit``'s damping) and whether the dictionary holds
    the Toon lobes (``fitted.TOONS``)."""
    damping: float
    toons: bool = False

    @property
    def label(self) -> str:
        return f"fitted {self.damping:g}" + " with toons" * self.toons


# The fits tried: relative errors and halfway to absolute ones, each without and with the Toon lobes. No weighting is
# best for every material, and the Toon lobes can mislead the fit's greedy choice (``fitted.TOONS``), so each is
# fitted and the Fitted mapping is the one closest on the comparison scenes.
VARIANTS = tuple(Variant(d, toons) for toons in (False, True) for d in (1.0, 0.5))


def fit_for(model_id: str, p, form: str, variant: Variant = VARIANTS[0], driven: fitted.Driven | None = None,
            progress=None) -> fitted.Fit:
    """The fit of ``p`` in ``form`` of ``variant`` (``fitted.fit``; ``fitted.fit_driven`` over a ``driven`` input,
    reporting ``progress(fraction)``), cached in memory and in ``cache_folder`` (an unreadable cache file is refitted
    and replaced)."""
    key = _variant_key(model_id, p, form, variant, driven)
    found = _cached(key)
    if found is not None:
        return found
    if driven is None:
        result = fitted.fit(*fit_problem(model_id, p, form), form, variant.damping, variant.toons)
    else:
        problems = [fit_problem(model_id, at(model_id, p, driven, j), form) for j in range(len(driven.values))]
        result = fitted.fit_driven(problems, driven, form, variant.damping, variant.toons, progress)
    return _stored(key, result)


def fits_for(model_id: str, p, form: str) -> dict:
    """{variant: fit} of ``p`` in ``form`` for every one of ``VARIANTS`` (``fit_for``'s caches), those not cached
    fitted together on one quadrature (``fitted.fit_variants``)."""
    keys = {v: _variant_key(model_id, p, form, v) for v in VARIANTS}
    found = {v: _cached(key) for v, key in keys.items()}
    missing = [v for v, f in found.items() if f is None]
    if missing:
        made = fitted.fit_variants(*fit_problem(model_id, p, form), form, [(v.damping, v.toons) for v in missing])
        found.update({v: _stored(keys[v], f) for v, f in zip(missing, made)})
    return found


def _variant_key(model_id: str, p, form: str, variant: Variant, driven: fitted.Driven | None = None) -> str:
    return f"{fit_key(model_id, p, form, driven)}-{variant.damping:g}{'-toons' * variant.toons}"


def fit_problem(model_id: str, q, form: str):
    """(backend_of, ref_eval, ref_albedo) of ``q`` in ``form``: what ``fitted.fit`` fits."""
    from . import _backend

    ref = reference_of(model_id)
    return (lambda wo: _backend(model_id, q, form, wo), lambda wi, wo: ref.eval(q, wi, wo),
            lambda wo: ref.furnace_albedo(q, wo, n=REFERENCE_ALBEDO_SAMPLES))


def _cached(key: str) -> fitted.Fit | None:
    """The fit stored under ``key`` in memory or in ``cache_folder``; None if absent or unreadable."""
    if key not in _fits:
        try:
            with np.load(cache_folder() / f"{key}.npz") as data:
                _fits[key] = fitted.Fit.from_arrays(data)
        except (OSError, ValueError, KeyError):
            return None
    return _fits[key]


def _stored(key: str, fit: fitted.Fit) -> fitted.Fit:
    _cache_write(cache_folder() / f"{key}.npz", lambda f: np.savez(f, **fit.to_arrays()))
    _fits[key] = fit
    return fit


def _cache_write(path: Path, write) -> None:
    """``write(file)`` into a temporary renamed to ``path`` (atomic); a cache that cannot be written is skipped."""
    tmp = path.with_name(f"{path.name}.{os.getpid()}.tmp")
    try:
        path.parent.mkdir(parents=True, exist_ok=True)
        with open(tmp, "wb") as f:
            write(f)
        os.replace(tmp, path)
    except OSError:
        tmp.unlink(missing_ok=True)


@dataclass
class Choice:
    """The mapping a material renders with: ``used`` ("analytic" or "fitted"), its ``fit`` (None for analytic),
    and the comparison scenes' errors of both (``errors[mapping][scene]``, ``error[mapping]`` their mean over the
    scenes that count, ``means[scene]`` the reference's); ``variant``: that of the closest fit."""
    used: str
    fit: fitted.Fit | None
    errors: dict = field(default_factory=dict)
    error: dict = field(default_factory=dict)
    means: dict = field(default_factory=dict)
    variant: Variant | None = None

    @property
    def note(self) -> str:
        """Why the errors say little, if they do."""
        if self.means and not any(m >= BACKLIT_MIN_MEAN for m in self.means.values()):
            return "the reference is black on every comparison scene: nothing to measure"
        return ""

    def summary(self) -> str:
        return describe({"used": self.used, "error": self.error, "note": self.note})


def describe(record: dict) -> str:
    """One line of a material's mapping record (``nodes.material.fit_record``, or a compare report's entry with
    ``predicted_error``): which mapping renders, both errors, the note."""
    errors = record.get("predicted_error", record.get("error", {}))
    shown = ", ".join(f"{name} {100 * e:.1f}%" for name, e in errors.items())
    note = f"; {record['note']}" if record.get("note") else ""
    measured = f" (predicted mean rel. RMSE on the comparison scenes: {shown})" if shown else ""
    return f"{record['used']} mapping{measured}{note}"


def comparison_errors(model_id: str, p, shaders: dict, resolution: int = CHOICE_RESOLUTION,
                      albedo_samples: int = SCENE_ALBEDO_SAMPLES, furnace_width: int | None = CHOICE_FURNACE_WIDTH,
                      images: dict | None = None, scenes=None):
    """({label: {scene: rel RMSE}}, {scene: reference mean}) of each shader in ``shaders`` ({label: (form, Fit or
    None)}, or (form, Fit or None, params) for a shader of other parameters than ``p``, such as a cheaper variant)
    against the reference of ``p`` on the comparison scenes (``reference.scenes.comparison_scenes``, or ``scenes``
    when given); ``images`` receives each shader's predicted image by (label, scene name)."""
    from ..reference import metrics
    from ..reference import scenes as ref_scenes

    errors, means = {label: {} for label in shaders}, {}
    for spec in scenes or ref_scenes.comparison_scenes(resolution, furnace_width):
        image = reference_image(model_id, p, spec, albedo_samples)
        mask = ref_scenes.scene_mask(spec)
        means[spec.name] = float(image[mask].mean())
        for label, (form, fit, *rendered) in shaders.items():
            predicted = predicted_image(model_id, rendered[0] if rendered else p, form, spec, fit)
            errors[label][spec.name] = metrics.rel_rmse(predicted, image, mask)
            if images is not None:
                images[(label, spec.name)] = predicted
    return errors, means


_references: dict = {}


def reference_image(model_id: str, p, spec, albedo_samples: int) -> np.ndarray:
    """The reference's image of a comparison scene, kept for the last few materials (both forms and both mappings
    are measured against the same one)."""
    from ..reference import scenes as ref_scenes

    key = (model_id, json.dumps(p.to_dict(), sort_keys=True), repr(spec), albedo_samples)
    if key not in _references:
        if len(_references) > 32:
            _references.clear()
        ref = reference_of(model_id)
        _references[key] = ref_scenes.reference_image(
            spec, lambda wi, wo: ref.eval(p, wi, wo),
            bsdf_albedo=lambda wo: ref.furnace_albedo(p, wo, n=albedo_samples))
    return _references[key]


def counted(errors: dict, means: dict) -> float:
    """The mean error over the scenes whose reference mean reaches ``BACKLIT_MIN_MEAN``."""
    values = [e for scene, e in errors.items() if means[scene] >= BACKLIT_MIN_MEAN and np.isfinite(e)]
    return float(np.mean(values)) if values else 0.0


def choose(model_id: str, p, form: str, mapping: str = "auto", driven: fitted.Driven | None = None,
           progress=None) -> Choice:
    """The mapping ``p`` renders with in ``form`` for the user's choice ``mapping`` (``MAPPING_KINDS``); models
    without a fitted mapping, and "analytic", render analytic without measuring anything. The measurements are
    cached with the fit. With a ``driven`` input, the choice is made at its middle value (module docstring)."""
    if mapping == "analytic" or not fittable(model_id):
        return Choice("analytic", None)
    if driven is not None:
        made = choose(model_id, at(model_id, p, driven, len(driven.values) // 2), form, mapping)
        if made.used == "fitted":
            made.fit = fit_for(model_id, p, form, made.variant, driven, progress)
        return made
    fits = fits_for(model_id, p, form)
    first_of = {}  # alike fits are measured once, as the first variant that made them
    for v, f in fits.items():
        first_of.setdefault(f.digest(), v)
    distinct = list(first_of.values())
    errors, means = _measured(model_id, p, form, {v.label: fits[v] for v in distinct})
    error = {name: counted(e, means) for name, e in errors.items()}
    best = min(distinct, key=lambda v: (error[v.label], VARIANTS.index(v)))
    errors, error = ({"analytic": e["analytic"], "fitted": e[best.label]} for e in (errors, error))
    used = "fitted" if mapping == "fitted" or error["fitted"] < error["analytic"] - AUTO_MARGIN else "analytic"
    return Choice(used, fits[best] if used == "fitted" else None, errors, error, means, best)


def _measured(model_id: str, p, form: str, fits: dict) -> tuple[dict, dict]:
    """``comparison_errors`` of the analytic mapping and of each fit ({label: Fit}), cached beside the fits
    (``<fit key>.json``)."""
    path = cache_folder() / f"{fit_key(model_id, p, form)}.json"
    try:
        data = json.loads(path.read_text())
        if set(data["errors"]) == {"analytic", *fits}:
            return data["errors"], data["means"]
    except (OSError, ValueError, KeyError):
        pass
    errors, means = comparison_errors(model_id, p, {"analytic": (form, None),
                                                    **{label: (form, fit) for label, fit in fits.items()}})
    _cache_write(path, lambda f: f.write(json.dumps({"errors": errors, "means": means}).encode()))
    return errors, means
