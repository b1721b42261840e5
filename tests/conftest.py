import logging
import sys
from pathlib import Path

import pytest

sys.path.insert(0, str(Path(__file__).parent))


@pytest.fixture
def quiet_pymodbus():
    """Timeouts make pymodbus log errors; the tests check them through the driver instead."""
    logger = logging.getLogger("pymodbus")
    level = logger.level
    logger.setLevel(logging.CRITICAL)
    yield
    logger.setLevel(level)


@pytest.fixture(scope="session")
def pg_cluster():
    """A throwaway PostgreSQL cluster for the session (tests/pgserver.py), stopped at the end;
    skips (fails under STATION_REQUIRE_PG=1) without PostgreSQL."""
    from pgserver import start_cluster

    cluster = start_cluster()
    yield cluster
    cluster.stop()


@pytest.fixture
def pg_url(pg_cluster):
    """The URL of a fresh empty database on the throwaway cluster."""
    return pg_cluster.new_database()


@pytest.fixture(autouse=True)
def record_store(tmp_path_factory, monkeypatch):
    """Every test's calibrations are recorded in a store of its own (STATION_DB), never in a
    station.db of the working tree (`station demo` without --out records into the working
    directory's); its URL."""
    url = f"sqlite:///{tmp_path_factory.mktemp('store') / 'station.db'}"
    monkeypatch.setenv("STATION_DB", url)
    return url
