"""Lobe pruning (issue 16; bpy-free): closures of a material's analytic mapping left out of both forms.

A mapping's ``shade`` calls closure methods on its backend in a fixed order, which may differ between the forms
(an anisotropic stack's node group adds a lobe where the Metallic BSDF cannot be as anisotropic), so a ``Pruned``
belongs to one form. ``Pruned(calls)`` names the calls (their indices in that order) that ``PrunedBackend`` drops;
everything else passes through. What only fed a dropped closure stays in the shader as dead code, which Cycles and
OSL's optimiser leave out: the cost model counts only ``live_operations``. ``lobe_energies`` measures what each call
carries: its directional albedo (the largest channel) at ``VIEWS``, the most light a material without it loses from
a view. ``prunable`` offers nested sets of the weakest calls while the energy left out stays within ``MAX_SHARE`` of
the material's albedo; Fit to budget (``budget``) measures each against the reference and keeps one only within
budget.
"""
from __future__ import annotations

import re
from dataclasses import dataclass

import numpy as np

CLOSURE_CALLS = ("glossy", "metal", "diffuse", "translucent", "transparent", "conductor", "dielectric", "beckmann",
                 "refraction", "velvet", "bulk")
MAX_SHARE = 0.1  # the most energy a pruned set leaves out, as a fraction of the material's largest albedo
# Views of the energy measurement: cosines down to grazing, azimuths for anisotropic closures.
VIEW_COSINES = (1.0, 0.85, 0.6, 0.35, 0.15, 0.05)
VIEW_AZIMUTHS = 4


@dataclass(frozen=True)
class Pruned:
    """The closure calls (indices in the mapping's order) left out, with the kind of each (``call_kinds``)."""
    calls: tuple[int, ...]
    kinds: tuple[str, ...] = ()

    LABEL = "pruned"  # in the names of the shaders that leave closures out

    def digest(self) -> str:
        return "-".join(map(str, self.calls))

    def describe(self) -> str:
        return ", ".join(f"{kind} #{i + 1}" for i, kind in zip(self.calls, self.kinds))

    def to_json(self) -> dict:
        return {"calls": list(self.calls), "kinds": list(self.kinds)}

    @classmethod
    def from_json(cls, data: dict) -> "Pruned":
        return cls(tuple(data["calls"]), tuple(data["kinds"]))


class PrunedBackend:
    """A backend that passes everything to ``b`` but the closure calls listed in ``calls``; ``kinds`` records the
    method name of every closure call seen."""

    def __init__(self, b, calls=()):
        self._b = b
        self._calls = set(calls)
        self.kinds: list[str] = []

    def __getattr__(self, name):
        attr = getattr(self._b, name)
        if name not in CLOSURE_CALLS:
            return attr

        def call(*args, **kw):
            self.kinds.append(name)
            if len(self.kinds) - 1 not in self._calls:
                attr(*args, **kw)

        return call


def shade(b, mapping, p, pruned: Pruned) -> None:
    mapping.shade(PrunedBackend(b, pruned.calls), p)


def views() -> np.ndarray:
    mu = np.repeat(VIEW_COSINES, VIEW_AZIMUTHS)
    phi = np.tile(np.arange(VIEW_AZIMUTHS) * (np.pi / VIEW_AZIMUTHS), len(VIEW_COSINES))
    s = np.sqrt(1.0 - mu * mu)
    return np.stack([s * np.cos(phi), s * np.sin(phi), mu], axis=1)


def call_kinds(model_id: str, p, form: str) -> list[str]:
    """The method of each closure call of the analytic mapping of ``p``, in order."""
    from . import MAPPINGS, numpy_backend

    recorder = PrunedBackend(numpy_backend(model_id, p, form, views()[:1]))
    MAPPINGS[model_id].shade(recorder, p)
    return recorder.kinds


def lobe_energies(model_id: str, p, form: str) -> np.ndarray:
    """The largest directional albedo (over ``views`` and channels) of each closure call alone."""
    from . import predicted_furnace

    n = len(call_kinds(model_id, p, form))
    wo = views()
    return np.array([np.max(predicted_furnace(model_id, p, form, Pruned(tuple(j for j in range(n) if j != i)))(wo))
                     for i in range(n)])


def prunable(model_id: str, p, form: str, max_share: float = MAX_SHARE) -> list[Pruned]:
    """Nested sets of the weakest closure calls (the weakest alone, then the two weakest, ...) while the summed
    energy left out stays within ``max_share`` of the material's largest albedo."""
    from . import predicted_furnace

    kinds = call_kinds(model_id, p, form)
    energy = lobe_energies(model_id, p, form)
    albedo = float(np.max(predicted_furnace(model_id, p, form)(views())))
    order = np.argsort(energy, kind="stable")
    out = []
    for k in range(1, len(order)):
        calls = tuple(sorted(int(i) for i in order[:k]))
        if np.sum(energy[order[:k]]) > max_share * albedo:
            break
        out.append(Pruned(calls, tuple(kinds[i] for i in calls)))
    return out


_TEMPORARY = re.compile(r"\bt\d+\b")


def live_operations(lines: list[str], outputs: list[str]) -> int:
    """How many of an ``OslBackend``'s temporaries (``lines``: ``type tN = expression;``) the ``outputs`` (closure
    expressions) depend on."""
    deps = {}
    for line in lines:
        name, expression = line.split("=", 1)
        deps[name.split()[-1]] = _TEMPORARY.findall(expression)
    live, todo = set(), [t for out in outputs for t in _TEMPORARY.findall(out)]
    while todo:
        t = todo.pop()
        if t not in live:
            live.add(t)
            todo.extend(deps.get(t, ()))
    return len(live)
