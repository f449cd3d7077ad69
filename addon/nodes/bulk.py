"""A simple BSDF (diffuse, rough conductor, rough dielectric) as a shader of its own: the reference bulks under a
micrograin layer, declared like SpongeCake's substrates (``models.spongecake.SUBSTRATE``)."""
from __future__ import annotations

from ..models import spongecake as model
from .spongecake import Socket, shade_substrate, substrate_sockets

ID = "bulk"
LABEL = "Bulk"


def structure_key(s: model.Substrate) -> tuple:
    return (s.type,)


def sockets(s: model.Substrate) -> list[Socket]:
    return substrate_sockets(s)


def input_values(s: model.Substrate) -> dict:
    return {k.name: getattr(s, k.param.name) for k in sockets(s)}


def with_values(s: model.Substrate, values: dict) -> model.Substrate:
    return model.Substrate(s.type, **{k.param.name: values[k.name] for k in sockets(s)})


def shade(b, s: model.Substrate) -> None:
    shade_substrate(b, s)
