"""``make bench``, the texture bake's throughput (docs/benchmarks.md, "Baking multiple scattering into textures"):
``bake.textures.bake_maps`` on synthetic textures, apart from SpongeCake's render timings so that it can be
measured again in seconds when a network changes (those renders take over an hour).

    python -m addon.bench.bake_speed --out docs      # this section alone, spliced into docs/benchmarks.md
"""
from __future__ import annotations

import argparse

import numpy as np

from .. import presets
from ..models import spongecake as model
from .common import timed

SECTION = "bake-speed"  # its marked section of docs/benchmarks.md
ROUNDS = 2  # bakes per measurement (the fastest counts)


def bake_seconds_per_megapixel(size: int) -> float:
    """``bake.textures.bake_maps`` on a synthetic ``size`` × ``size`` input: 2-layer fabric, textures on the top
    layer's albedo and roughness and the bottom layer's thickness; the network loaded outside the timing."""
    from ..bake import spongecake as ms
    from ..bake import textures

    p = model.params_from_dict({**presets.load("spongecake", "fabric"), "multiple_scattering": True})
    rng = np.random.default_rng(0)
    inputs = {(0, "albedo"): rng.uniform(0.2, 0.9, (size, size, 3)),
              (0, "roughness"): rng.uniform(0.05, 0.5, (size, size)),
              (1, "thickness"): rng.uniform(1.0, 8.0, (size, size))}
    ms.network(len(p.layers))
    seconds = min(timed(lambda: textures.bake_maps(p, inputs)) for _ in range(ROUNDS))
    return seconds / (size * size / 1e6)


def network_label() -> str:
    """The network the bake runs, from its manifest: its hidden widths and when it was trained."""
    from ..bake import spongecake as ms

    net = ms.network(2)
    widths = " × ".join(str(w) for w in net.hidden)
    return f"the two-layer network, hidden {widths}, trained {net.manifest.get('date', '?')}"


def speed(size: int) -> str:
    per_mp = bake_seconds_per_megapixel(size)
    return "\n".join([
        "## Baking multiple scattering into textures", "",
        f"`bake.textures.bake_maps`, 2-layer fabric, synthetic {size}×{size} textures on three inputs (network "
        f"inference and packing into RGBA maps, no file I/O; {network_label()}; fastest of {ROUNDS}): "
        f"**{per_mp:.2f} s per megapixel**.", ""])


def main(argv=None) -> int:
    """Measure this section alone and splice it into ``--out``/benchmarks.md."""
    from . import splice_alone
    from .spongecake import MS_DEFAULT

    ap = argparse.ArgumentParser(prog="python -m addon.bench.bake_speed", description=main.__doc__)
    ap.add_argument("--out", default="docs")
    ap.add_argument("--size", type=int, default=MS_DEFAULT.bake_size, help="texture side")
    args = ap.parse_args(argv)
    splice_alone(args.out, "benchmarks.md", SECTION, speed(args.size), "python -m addon.bench.bake_speed")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
