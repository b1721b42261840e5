"""The calibration record store (station.records, docs/records.md) on SQLite and on a real
PostgreSQL server (tests/pgserver.py: a throwaway cluster; skipped without PostgreSQL unless
STATION_REQUIRE_PG=1): round trip, migrations, refusals, the queries, the run rules, kills
during writes, two writers."""

import dataclasses
import signal
import sqlite3
import subprocess
import sys
import time
from pathlib import Path

import numpy as np
import pytest
from recordmaker import synthetic_record, when

from station.errors import InputError, NewerStoreError, RecordStoreError
from station.records import spc
from station.records.analysis import drift, fleet, history
from station.records.query import Selection
from station.records.store import open_store

MAKER = Path(__file__).with_name("recordmaker.py")


@pytest.fixture(params=["sqlite", "postgresql"])
def url(request, tmp_path):
    """A fresh store of each backend."""
    if request.param == "sqlite":
        return f"sqlite:///{tmp_path / 'station.db'}"
    return request.getfixturevalue("pg_url")


def test_a_record_comes_back_whole_and_once(url):
    rng = np.random.default_rng(1)
    records = [synthetic_record(rng, "SN1", when(k)) for k in (2, 0, 1)]
    with open_store(url) as store:
        ids = [store.add(r) for r in records]
        assert store.add(records[0]) is None  # the same calibration file (sha256): once
        got = store.history("SN1")
    assert len(set(ids)) == 3 and None not in ids
    assert [g.created for g in got] == [when(0), when(1), when(2)]  # oldest first
    for g in got:
        sent = next(r for r in records if r.calibration_sha256 == g.calibration_sha256)
        assert g.parameters == tuple(sorted(sent.parameters, key=lambda p: (p.name, p.sensor)))
        assert dataclasses.replace(g, id=None, recorded=None, parameters=()) == \
            dataclasses.replace(sent, parameters=())


def test_migrations_are_numbered_and_applied_once(url):
    with open_store(url) as store, store.transaction() as cur:
        cur.execute("SELECT version, description FROM schema_version")
        first = cur.fetchall()
    with open_store(url) as store, store.transaction() as cur:
        cur.execute("SELECT version FROM schema_version")
        assert [v for v, in cur.fetchall()] == [1]
    assert first[0][0] == 1 and first[0][1]


def test_a_store_of_a_newer_station_is_refused_unwritten(url):
    with open_store(url) as store, store.transaction() as cur:
        cur.execute(store.sql("INSERT INTO schema_version (version, applied, description) "
                              "VALUES (?, ?, ?)"), (99, when(0), "from the future"))
    with pytest.raises(NewerStoreError, match="newer station.*upgrade"):
        open_store(url)


def test_an_unreachable_server_and_a_bad_url_say_what_to_do(tmp_path):
    with pytest.raises(RecordStoreError, match="cannot reach the record store.*server is "
                                               "running") as err:
        open_store(f"postgresql://station:secret@/nodb?host={tmp_path}")
    assert "secret" not in str(err.value)  # the password never printed
    with pytest.raises(InputError, match="sqlite:///PATH"):
        open_store("mysql://host/db")
    with pytest.raises(RecordStoreError, match="no record store at"):
        open_store(f"sqlite:///{tmp_path / 'absent.db'}", create=False)


def test_query_words_are_values_never_sql(url):
    rng = np.random.default_rng(2)
    with open_store(url) as store:
        store.add(synthetic_record(rng, "SN1", when(0), model="m1", bench="b1"))
        store.add(synthetic_record(rng, "SN2", when(1), model="m2", bench="b1"))
        hostile = Selection.parse("serial=x';DROP_TABLE_calibrations;--")
        assert store.records(hostile) == []
        assert store.count() == 2
        picked = store.records(Selection.parse(f"model=m2 since={when(1)}"))
        assert [r.unit_serial for r in picked] == ["SN2"]
        assert store.records(Selection.parse(f"bench=b1 until={when(1)}"))[0].unit_serial == "SN1"
    with pytest.raises(InputError, match="unknown key 'colour'"):
        Selection.parse("colour=red")
    with pytest.raises(InputError, match="KEY=VALUE"):
        Selection.parse("model")


def test_drift_in_sigmas_between_consecutive_calibrations():
    rng = np.random.default_rng(3)
    a, b = synthetic_record(rng, "SN1", when(0)), synthetic_record(rng, "SN1", when(1))
    d = drift(a, b)
    assert len(d) == len(a.parameters)
    by = {(p.name, p.sensor): p for p in a.parameters}
    for step in d:
        p = next(q for q in b.parameters if (q.name, q.sensor) == (step["parameter"],
                                                                    step["sensor"]))
        q = by[(p.name, p.sensor)]
        assert step["sigmas"] == pytest.approx((p.value - q.value) / np.hypot(p.sigma, q.sigma))
    assert abs(d[0]["sigmas"]) == max(abs(s["sigmas"]) for s in d)
    h = history([a, b], "SN1")
    assert h["largest_drift"]["sigmas"] == d[0]["sigmas"]


@pytest.mark.parametrize(("z", "rule", "at"), [
    ([0, 0.5, -0.5, 3.5], "beyond_3_sigma", 3),
    ([0, 2.5, 0.1, 2.2], "2_of_3_beyond_2", 3),
    ([-0.1, *[0.3] * 8], "8_on_one_side", 8),
    ([0.5, -1.0, -0.8, -0.5, 0.0, 0.4, 0.9], "6_trending", 6),
])
def test_each_run_rule_fires_where_its_pattern_completes(z, rule, at):
    hits = spc.run_rules(z)
    assert (at, rule) in hits
    assert all(i >= at for i, r in hits if r == rule)


def test_run_rules_false_alarm_rates_of_a_stable_process():
    """Under a stable normal process each rule fires at about its theoretical rate per point
    (module docstring); 200,000 points, 5-sigma binomial bounds (runs correlate rules 3 and 4:
    their bounds are wider)."""
    n = 200_000
    z = np.random.default_rng(4).standard_normal(n)
    hits = spc.run_rules(z)
    rate = {rule: sum(r == rule for _, r in hits) / n for rule in spc.RULES}
    p1 = 2 * 0.00134990
    assert abs(rate["beyond_3_sigma"] - p1) < 5 * np.sqrt(p1 / n)
    assert rate["8_on_one_side"] == pytest.approx(2 * 0.5 ** 8, rel=0.15)
    assert rate["6_trending"] == pytest.approx(2 / 720, rel=0.15)  # 6 values in one order of 6!
    assert 0.001 < rate["2_of_3_beyond_2"] < 0.004


def test_a_chart_needs_a_baseline_that_varies():
    assert spc.chart([1.0] * 5, baseline=10) is None
    assert spc.chart([1.0] * 20, baseline=10) is None
    c = spc.chart(np.r_[np.random.default_rng(5).normal(0, 1, 10), 10.0], baseline=10)
    assert c.first == 10 and c.violations[0] == (10, "beyond_3_sigma")


def _kill_writer_at_random(url: str, seed: int, rng) -> None:
    """Start a writer (tests/recordmaker.py), wait until it has written, SIGKILL it at a random
    moment of its writing."""
    child = subprocess.Popen([sys.executable, str(MAKER), url, "0", str(seed)],
                             stdout=subprocess.PIPE, text=True)
    try:
        assert child.stdout.readline().strip() == "ready"
        time.sleep(rng.uniform(0.0, 0.4))
    finally:
        child.send_signal(signal.SIGKILL)
        child.wait()
        child.stdout.close()


def test_twenty_kills_during_writes_leave_every_record_whole(url):
    rng = np.random.default_rng(6)
    for k in range(20):
        _kill_writer_at_random(url, k, rng)
    with open_store(url) as store:
        assert store.incomplete() == []
        assert store.integrity() in ("ok", None)
        count = store.count()
        assert count >= 20  # every writer committed its first record before it was killed
        assert len(store.records(Selection.parse("serial=SN3-0"))) >= 1  # a fresh query works
    if url.startswith("sqlite:///"):
        path = url.removeprefix("sqlite:///")
        with sqlite3.connect(path) as raw:  # a reader that is not the station
            assert raw.execute("PRAGMA integrity_check").fetchone()[0] == "ok"


def test_two_writers_at_once_lose_no_record(url):
    n = 150
    children = [subprocess.Popen([sys.executable, str(MAKER), url, str(n), str(seed)],
                                 stdout=subprocess.DEVNULL) for seed in (101, 102)]
    assert [c.wait() for c in children] == [0, 0]
    with open_store(url) as store:
        assert store.count() == 2 * n
        assert store.incomplete() == []


def test_stations_opening_a_new_store_at_once_make_its_schema_once(url):
    """Six processes open one new store together: each migrates or waits for the one that does
    (PostgreSQL: the advisory lock before the version table; seen racing without it)."""
    code = ("import sys; from station.records.store import open_store; "
            "open_store(sys.argv[1]).close()")
    children = [subprocess.Popen([sys.executable, "-c", code, url]) for _ in range(6)]
    assert [c.wait() for c in children] == [0] * 6
    with open_store(url) as store, store.transaction() as cur:
        cur.execute("SELECT version FROM schema_version")
        assert [v for v, in cur.fetchall()] == [1]


def test_fleet_yield_and_distributions(url):
    rng = np.random.default_rng(7)
    verdicts = ["PASS"] * 17 + ["FAIL"] * 2 + ["MARGINAL"]
    with open_store(url) as store:
        for k, v in enumerate(verdicts):
            store.add(synthetic_record(rng, f"SN{k % 7}", when(k), verdict=v,
                                       rate_error=float(rng.normal(0, 1e-5))))
        report = fleet(store, Selection(), baseline=10)
    assert report["records"] == 20 and report["units"] == 7
    assert report["yield"] == {"judged": 20, "PASS": 17, "FAIL": 2, "MARGINAL": 1,
                               "fraction": 17 / 20}
    charts = report["models"]["imu6"]["parameters"]
    assert len(charts) == 18 and all(c["n"] == 20 and c["chart"] for c in charts)
    assert report["benches"]["bench1"]["table_rate_error"]["points"] == 20
