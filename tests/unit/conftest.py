"""Fixtures the unit tests share."""
from functools import lru_cache

import pytest

from addon.models import spongecake as spongecake_model
from addon.nodes import spongecake as spongecake_nodes
from addon.reference import spongecake


@pytest.fixture
def coarse_energy_tables(monkeypatch):
    """SpongeCake's reference energy tables from 64 samples per view and 4 view azimuths, and the Cycles forms' view
    tables on 8 × 8 views: the same arithmetic at a sixty-fourth of the samples and an eighth of the azimuths (a
    thirty-second of the views), for tests of what the tables feed (extremes, the measuring code), not of the
    estimate's noise. The coarse tables are cached apart: the full tables cached before stay for the tests after."""
    monkeypatch.setattr(spongecake, "ENERGY_SAMPLES", 64)
    monkeypatch.setattr(spongecake_model, "ENERGY_AZIMUTHS", 4)
    monkeypatch.setattr(spongecake_model, "VIEW_ENERGY_GRID", (8, 8))
    for module, name in ((spongecake, "_energy_tables"), (spongecake_nodes, "_budget_table"),
                         (spongecake_nodes, "_ms_values")):
        cached = getattr(module, name)
        monkeypatch.setattr(module, name, lru_cache(maxsize=cached.cache_info().maxsize)(cached.__wrapped__))
