"""A recorded free-static session (`station.protocols.static`) -> the accelerometer rows of its
still poses.

Every accelerometer channel of the stream (unit m/s^2) is calibrated; the session's metadata names
them (`channels`), else their unit does (`accelerometer_channels`, which the live protocol uses
too).
"""

import dataclasses

import numpy as np

from station.errors import CalibrationInputError
from station.reduce.still import ACCELEROMETER, StillReadings, still_readings


def accelerometer_channels(units) -> np.ndarray:
    """Indices of the stream channels in m/s^2; CalibrationInputError when fewer than 3."""
    channels = np.flatnonzero([u == ACCELEROMETER for u in units])
    if len(channels) < 3:
        raise CalibrationInputError(
            f"the stream has {len(channels)} accelerometer channels (unit {ACCELEROMETER}); "
            "free-static calibration needs at least 3.",
            "Use a device profile whose [imu] units mark the accelerometer channels m/s^2.")
    return channels


def static_readings(session, stream: str = "imu", **detector) -> StillReadings:
    """The accelerometer rows of the still poses of a free-static session (`still_readings`, with
    its `trim` and detector options)."""
    still = still_readings(session, stream, **detector)
    channels = session_channels(session, stream)
    return dataclasses.replace(still, M=still.M[channels], sigma=still.sigma[channels])


def session_channels(session, stream: str = "imu") -> np.ndarray:
    """Indices of the accelerometer channels of a free-static session's stream: the metadata's
    (checked: untrusted), or those in m/s^2."""
    m = len(session.specs[stream].channels)
    channels = session.metadata.get("channels")
    if channels is None:
        return accelerometer_channels(session.specs[stream].units)
    if not (isinstance(channels, list) and all(type(c) is int and 0 <= c < m for c in channels)
            and len(set(channels)) == len(channels) >= 3):
        raise CalibrationInputError(f"{session.path} records accelerometer channels {channels!r}.",
                                    "The session file is damaged or not from the free-static "
                                    "protocol.")
    return np.array(channels)
