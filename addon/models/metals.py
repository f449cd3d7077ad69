"""Complex indices of refraction n + ik (R, G, B at about 650, 550, 450 nm) of common metals, rounded from published
tables; the conductor choices of every dialog (thin-coat bases, conductor grains, anisotropic-stack bases)."""

METALS = {
    "aluminium": ((1.657, 0.880, 0.521), (9.224, 6.270, 4.837)),
    "gold": ((0.143, 0.374, 1.442), (3.983, 2.385, 1.603)),
    "copper": ((0.271, 0.677, 1.316), (3.609, 2.625, 2.292)),
    "silver": ((0.159, 0.145, 0.135), (3.929, 3.190, 2.381)),
    "iron": ((2.87, 2.95, 2.65), (3.08, 2.93, 2.81)),
}


def named(ior, k, rel_tol: float = 1e-3) -> str | None:
    """The name of the metal whose (n, k) are ``ior``, ``k`` (to ``rel_tol``), or None."""
    values = tuple(ior) + tuple(k)
    for name, (n, kappa) in METALS.items():
        if all(abs(a - c) <= rel_tol * max(abs(c), 1e-12) for a, c in zip(values, n + kappa)):
            return name
    return None
