"""The calibration record store: every calibration of every unit, with the station, bench,
devices and software that made it, so that a unit's drift, a bench's drift and a lot's yield are
queries, not file hunts (docs/records.md).

    record     what one record holds (Record, Parameter), built from a calibration file
    sources    where it came from: the session's sha256, model, bench, devices, health figures
    store      the one interface (Store, open_store, store_url); sqlite and postgres backends
    schema     the schema and its numbered migrations (schema_version)
    query      which records a question is about (Selection: "model=X since=2026-11-01")
    analysis   a unit's history and drift, the fleet report
    spc        the Shewhart X chart and the Western Electric / Nelson run rules
    importing  fill the store from existing folders of sessions and calibration files
"""
