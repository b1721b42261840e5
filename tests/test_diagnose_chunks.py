"""Issue 35: the effects' signatures are made a few positions at a time (station.diagnose.linear.
signature_parts), so that diagnose holds no signature of the session's size; made one position at
a time or all at once, every fit is the same to rounding."""

import importlib.util
from pathlib import Path

import numpy as np
import pytest

from station.diagnose import linear, model

ROOT = Path(__file__).resolve().parents[1]
spec = importlib.util.spec_from_file_location("bench_diagnose", ROOT / "bench" / "diagnose.py")
bench = importlib.util.module_from_spec(spec)
spec.loader.exec_module(bench)

CHUNKED = {"earth_rate": "earth_rate", "axis_wobble": "axis_wobble", "latency": "latency",
           "scale_nonlinearity": "scale_nonlinearity", "rate_error": "rate_error_encoder"}
"""The extensions whose signatures are made in chunks -> the bench case that hides each (the
encoder's rate error: its gain's signature is made in chunks, the random effect's is s)."""


def fitted(data, name: str, positions: int, monkeypatch) -> dict:
    """The parameters of `name` fitted jointly with the calibration, signatures made
    `positions` positions at a time."""
    monkeypatch.setattr(linear, "POSITIONS", positions)
    fit = model.fit(data, [name], model.nominal(data), iterations=1)
    return {"values": fit.fitted[name].values, "sigma": fit.fitted[name].sigma,
            "chi2": fit.chi2, "a": fit.calibration.a}


@pytest.mark.parametrize("name", CHUNKED)
def test_a_fit_does_not_depend_on_the_chunk(name, monkeypatch):
    data, _ = bench.session(CHUNKED[name], 3, 35, n=8, fs=50.0)
    one, whole = (fitted(data, name, p, monkeypatch) for p in (1, data.shape[0]))
    assert one["chi2"] == pytest.approx(whole["chi2"], rel=1e-9)
    np.testing.assert_allclose(one["a"], whole["a"], rtol=1e-9, atol=1e-15)
    for part in ("values", "sigma"):
        for key, value in whole[part].items():
            np.testing.assert_allclose(one[part][key], value, rtol=1e-9, atol=1e-15,
                                       err_msg=f"{part} {key}")
