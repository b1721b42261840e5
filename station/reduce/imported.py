"""An imported recording (`station import`, protocol "import") -> the still poses of its
accelerometer stream, the free-static path of the command line; or, for a magnetometer stream (in
T), the block readings of a continuous rotation (`station.reduce.blocks`: hard and soft iron).

The recording carries no protocol events: every still interval the detector finds is a pose
(`station.reduce.still.still_readings`), detected on the accelerometer channels by default (the
gyro can veto with `--still-channels acc+gyro`, from the same or its own stream). The stream
calibrated by default is the one whose channels are in m/s^2. With `faces` (`--faces`) the poses
are the faces of a right-angle block in one mounting: each is labelled with its face
(`station.reduce.iron.on_faces`), and the solver takes the right-angle constraints of Hwangbo &
Kanade's Eq. (15), which separate the misalignments from the scale factors when the poses are only
the six axis-aligned directions (a free ellipsoid cannot).
"""

import dataclasses

import numpy as np

from station.errors import CalibrationInputError
from station.reduce.blocks import (
    MAGNETOMETER,
    BlockReadings,
    magnetometer_channels,
    magnetometer_readings,
)
from station.reduce.iron import IronReadings, on_faces
from station.reduce.static import session_channels, static_readings
from station.reduce.still import ACCELEROMETER, GYRO, StillReadings
from station.reduce.stillness import StillOptions


def default_stream(session) -> str:
    """The one stream with accelerometer channels (m/s^2), else the one magnetometer stream (T);
    an error naming them when there are none or several."""
    for unit in (ACCELEROMETER, MAGNETOMETER):
        found = [name for name, spec in session.specs.items() if unit in spec.units]
        if len(found) == 1:
            return found[0]
        if found:
            raise CalibrationInputError(
                f"{session.path} has {len(found)} streams in {unit}: {', '.join(found)}.",
                "Choose the stream to calibrate with --stream NAME.")
    raise CalibrationInputError(
        f"{session.path} has no stream in {ACCELEROMETER} or {MAGNETOMETER} (streams: "
        f"{', '.join(session.specs)}).",
        "Import the accelerometer with a unit in m/s^2 (m/s^2, g, counts:m/s^2) or the "
        "magnetometer in T (T, uT, gauss, counts:T).")


def imported_readings(session, stream: str, trim: float = 0.0, still: StillOptions | None = None,
                      faces: bool = False) -> StillReadings | IronReadings | BlockReadings:
    """The accelerometer rows of every still pose of an imported recording (`static_readings`);
    `still`: the detector settings, channels "acc" unless given; `faces`: the poses are faces of
    a right-angle block (`block_faces`). A magnetometer stream (T) gives its block readings
    instead (no still poses: the unit turns all the time)."""
    units = session.specs[stream].units
    if MAGNETOMETER in units:
        if still is not None or trim or faces:
            raise CalibrationInputError(
                f"stream {stream!r} is a magnetometer (T), calibrated from blocks of a continuous "
                "rotation, not still poses.",
                "Leave out --rest, --threshold, --still-channels, --min-still, --trim and "
                "--faces.")
        return magnetometer_readings(session, stream)
    if ACCELEROMETER not in units and GYRO in units:
        raise CalibrationInputError(
            f"stream {stream!r} is a gyro ({GYRO}): it has no still poses of its own to "
            "calibrate.", "`station solve --stream NAME` calibrates an imported gyro from the "
                          "turns between the accelerometer's still poses (docs/hand-turns.md).")
    still = still or StillOptions()
    still = dataclasses.replace(still, channels=still.channels or "acc")
    readings = static_readings(session, stream, trim=trim, still=still)
    return block_faces(readings, stream) if faces else readings


def block_faces(readings: StillReadings, stream: str) -> IronReadings:
    """The still poses of a triad, each labelled with the face of a right-angle block it stands
    on (`station.reduce.iron.recognise_faces` of its up direction, the nominal axes the
    identity; one mounting), for the constraints of Eq. (15)."""
    m = readings.M.shape[0]
    if m != 3:
        raise CalibrationInputError(
            f"--faces labels the poses of one accelerometer triad, but stream {stream!r} has {m} "
            "accelerometer channels.", "Leave out --faces, or import one triad as its own "
                                       "stream.")
    return on_faces(readings, np.eye(3), advice="The poses are not all faces of one right-angle "
                    "block: leave out --faces to calibrate them as free still poses.")


def carry_samples(session, gyro_stream: str, acc_stream: str, readings: StillReadings) -> tuple:
    """(gyro (K, 3) rad/s, accelerometer (K, 3) m/s^2, still intervals (P, 2) [start, stop)) of
    an import whose accelerometer's still poses (`readings`, their detection kept) have hand turns
    between them, for `station.solve.gyro_carry.calibrate_carry`: the gyro triad on the
    accelerometer's samples."""
    gyro = imported_channels(session, gyro_stream)
    if len(gyro) != 3:
        raise CalibrationInputError(
            f"stream {gyro_stream!r} has {len(gyro)} channels in {GYRO}; the turns between still "
            "poses calibrate one gyro triad.", "Import the three gyro axes as one stream.")
    data, acc = session.stream(gyro_stream), session.stream(acc_stream)
    if not np.array_equal(data.seq, acc.seq) or len(readings.times) != len(acc.seq):
        raise CalibrationInputError(
            f"{session.path}: the gyro stream {gyro_stream!r} is not on the samples of the "
            f"accelerometer {acc_stream!r}.", "Import the accelerometer and gyro on one time "
                                             "base (one file, or the same time column).")
    z = acc.to_si()[:, session_channels(session, acc_stream)]
    return data.to_si()[:, gyro], z, readings.detection.intervals


def imported_channels(session, stream: str):
    """The calibrated channels: those in T of a magnetometer stream, those in rad/s of a gyro
    stream (no m/s^2), else the accelerometer's."""
    units = session.specs[stream].units
    if MAGNETOMETER in units:
        return magnetometer_channels(session, stream)
    if GYRO in units and ACCELEROMETER not in units:
        return np.flatnonzero([u == GYRO for u in units])
    return session_channels(session, stream)
