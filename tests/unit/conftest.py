"""Fixtures the unit tests share."""
import pytest

from addon.models import spongecake as spongecake_model
from addon.nodes import spongecake as spongecake_nodes
from addon.reference import spongecake


@pytest.fixture
def coarse_energy_tables(monkeypatch):
    """SpongeCake's reference energy tables from 64 samples per view and 4 view azimuths, and the Cycles forms' view
    tables on 8 × 8 views: the same arithmetic at a sixty-fourth of the samples and an eighth of the azimuths (a
    thirty-second of the views), for tests of what the tables feed (extremes, the measuring code), not of the
    estimate's noise."""
    monkeypatch.setattr(spongecake, "ENERGY_SAMPLES", 64)
    monkeypatch.setattr(spongecake_model, "ENERGY_AZIMUTHS", 4)
    monkeypatch.setattr(spongecake_model, "VIEW_ENERGY_GRID", (8, 8))
    caches = (spongecake._energy_tables, spongecake_nodes._budget_table, spongecake_nodes._ms_values)
    for cache in caches:
        cache.cache_clear()
    yield
    for cache in caches:
        cache.cache_clear()
