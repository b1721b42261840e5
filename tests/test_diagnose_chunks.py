"""Issue 35: the twin's series, the residuals and the effects' signatures are made a chunk of
positions at a time (station.diagnose.data.RotaryData.chunks), so that diagnose holds no series
of the session's size; made one position at a time or all at once, every fit is the same to
rounding."""

import importlib.util
from pathlib import Path

import numpy as np
import pytest

from station.diagnose import data as session_data
from station.diagnose import model

ROOT = Path(__file__).resolve().parents[1]
spec = importlib.util.spec_from_file_location("bench_diagnose", ROOT / "bench" / "diagnose.py")
bench = importlib.util.module_from_spec(spec)
spec.loader.exec_module(bench)

CHUNKED = {"earth_rate": "earth_rate", "axis_wobble": "axis_wobble", "latency": "latency",
           "scale_nonlinearity": "scale_nonlinearity", "rate_error": "rate_error_encoder",
           "bias_drift": "bias_drift", "saturation": "saturation",
           "temperature": "temperature_motor"}
"""Every extension -> the bench case that hides it (the encoder's rate error: its gain's
signature is made in chunks too; bias_drift: its heating carries over from one position to the
next, across the chunks' borders; temperature: a session recording the unit's temperature)."""


def session(case: str):
    """A short simulated session of 8 positions hiding the bench case `case`."""
    make = bench.warm_session if case in bench.WARM else bench.session
    return make(case, 3, 35, n=8, fs=50.0)[0]


def fitted(data, name: str, positions: int, monkeypatch) -> dict:
    """The parameters of `name` fitted jointly with the calibration, signatures made
    `positions` positions at a time."""
    monkeypatch.setattr(session_data, "POSITIONS", positions)
    fit = model.fit(data, [name], model.nominal(data), iterations=1)
    return {"values": fit.fitted[name].values, "sigma": fit.fitted[name].sigma,
            "chi2": fit.chi2, "a": fit.calibration.a}


@pytest.mark.parametrize("name", CHUNKED)
def test_a_fit_does_not_depend_on_the_chunk(name, monkeypatch):
    data = session(CHUNKED[name])
    one, whole = (fitted(data, name, p, monkeypatch) for p in (1, data.shape[0]))
    assert one["chi2"] == pytest.approx(whole["chi2"], rel=1e-9)
    close(one["a"], whole["a"], "a")
    for part in ("values", "sigma"):
        for key, value in whole[part].items():
            close(one[part][key], value, f"{part} {key}")


def close(actual, desired, what: str) -> None:
    """Equal to rounding relative to the array's own scale: the chunks sum in another order
    (1e-16 relative), which the calibration's solve amplifies by its condition number, so an
    entry far below the largest (an off-diagonal of a) keeps that absolute error, not a
    relative one."""
    desired = np.asarray(desired, float)
    finite = np.abs(desired[np.isfinite(desired)])
    scale = float(finite.max(initial=0.0))
    np.testing.assert_allclose(actual, desired, rtol=1e-9, atol=1e-9 * scale, err_msg=what)
