"""A thermal campaign (station.session.campaign) -> one Soak per recorded session.

Each session done is a rotary session at one chamber setpoint: its gyro channels (every channel
not in K) reduce to Eq. (18) readings (`rotary_readings`) with their biases from the static windows
(`pooled_static_bias`: their scatter pooled over the soaks, so a tempco's z is Student's t of
sum(n_k - 1) degrees of freedom), the readings `station.solve.temperature.fit_temperature` takes;
the soak's temperature is the mean of the session's recorded temperature channel (the unit's own
sensor, K) over the whole session, not the setpoint nor the chamber's air.
"""

import math
from dataclasses import dataclass

import numpy as np

from station.errors import CalibrationInputError
from station.model.temperature import Soak, check_kelvin
from station.reduce.rotary import pooled_static_bias, rotary_channels, rotary_readings
from station.session import Session
from station.session.campaign import Campaign


@dataclass(frozen=True)
class CampaignSoaks:
    """The soaks of a campaign and what its calibration file needs.

    soaks   : [Soak], in the order recorded; files: their session paths
    rate    : the table rate (rad/s), the stimulus magnitude, the same in every session
    sensors, units, counts_per_unit : of the calibrated (gyro) channels
    """

    soaks: list
    files: list
    rate: float
    sensors: list
    units: list
    counts_per_unit: np.ndarray
    unit_serial: str


def campaign_soaks(path) -> CampaignSoaks:
    """The soaks of the campaign at `path` (its directory or manifest); CalibrationInputError
    when fewer than two soaks are done or the sessions disagree in stream or table rate."""
    campaign = Campaign.load(path)
    done = campaign.done()
    if len(done) < 2:
        raise CalibrationInputError(
            f"{campaign.directory}: {len(done)} soak(s) recorded; a temperature model needs at "
            "least 2.", f"Continue the campaign: `station resume {campaign.directory}`.")
    reduced, temperatures, first = [], [], None
    for _setpoint, file in done:
        with Session.open(file) as session:
            spec = session.specs["imu"]
            rate = session.metadata.get("settings", {}).get("rate")
            if type(rate) not in (int, float) or not math.isfinite(rate) or rate == 0:
                raise CalibrationInputError(f"{file} records no usable table rate ({rate!r}).",
                                            "Record the soak again.")
            key = (spec.channels, spec.units, tuple(spec.counts_per_unit), abs(float(rate)))
            if first is not None and key != first:
                raise CalibrationInputError(
                    f"{file}: its stream or table rate differs from the campaign's first "
                    "session.", "Solve sessions of one unit, one device profile and one rate.")
            first = key
            gyros = rotary_channels(session)
            reduced.append(rotary_readings(session))
            temperatures.append(session_temperature(session, file))
            unit_serial = session.unit_serial
    soaks = [Soak(t, r.M, r.sigma, bias=b["bias"], bias_sigma=b["bias_sigma"])
             for t, r, b in zip(temperatures, reduced, pooled_static_bias(reduced), strict=True)]
    channels, units, counts, rate = first
    return CampaignSoaks(soaks, [str(f) for _, f in done], rate, [channels[i] for i in gyros],
                         [units[i] for i in gyros], np.asarray(counts)[gyros], unit_serial)


def session_temperature(session, file) -> float:
    """K: the mean of a session's temperature channel (the first in K) over all its samples."""
    spec = session.specs["imu"]
    kelvin = [i for i, u in enumerate(spec.units) if u == "K"]
    if not kelvin:
        raise CalibrationInputError(f"{file} records no temperature channel (unit K).",
                                    "Record the campaign with a device profile that streams the "
                                    "unit's temperature (e.g. imu12_serial_temp).")
    counts = session.stream("imu", columns=("counts",)).counts[:, kelvin[0]]
    return float(check_kelvin(np.mean(counts) / spec.counts_per_unit[kelvin[0]],
                              f"{file}: the mean recorded temperature")[0])
