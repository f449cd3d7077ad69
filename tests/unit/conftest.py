"""Fixtures the unit tests share."""
import pytest

from addon.models import spongecake as spongecake_model
from addon.reference import spongecake


@pytest.fixture
def coarse_energy_tables(monkeypatch):
    """SpongeCake's reference energy tables from 64 samples per view and 4 view azimuths: the same arithmetic at a
    sixty-fourth of the samples and an eighth of the azimuths, for tests of what the tables feed (extremes, the
    measuring code), not of the estimate's noise."""
    monkeypatch.setattr(spongecake, "ENERGY_SAMPLES", 64)
    monkeypatch.setattr(spongecake_model, "ENERGY_AZIMUTHS", 4)
    spongecake._energy_tables.cache_clear()
    yield
    spongecake._energy_tables.cache_clear()
