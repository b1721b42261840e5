"""An imported recording (`station import`, protocol "import") -> the still poses of its
accelerometer stream, the free-static path of the command line.

The recording carries no protocol events: every still interval the detector finds is a pose
(`station.reduce.still.still_readings`), detected on the accelerometer channels by default (the
gyro can veto with `--still-channels acc+gyro`, from the same or its own stream). The stream
calibrated by default is the one whose channels are in m/s^2.
"""

import dataclasses

from station.errors import CalibrationInputError
from station.reduce.static import static_readings
from station.reduce.still import ACCELEROMETER, StillReadings
from station.reduce.stillness import StillOptions


def accelerometer_stream(session) -> str:
    """The name of the one stream with accelerometer channels (m/s^2); an error naming them when
    there are none or several."""
    found = [name for name, spec in session.specs.items() if ACCELEROMETER in spec.units]
    if len(found) != 1:
        raise CalibrationInputError(
            f"{session.path} has {len(found) or 'no'} streams in {ACCELEROMETER}"
            f"{': ' + ', '.join(found) if found else ''} (streams: {', '.join(session.specs)}).",
            "Choose the stream to calibrate with --stream NAME." if found else
            "Import the accelerometer with a unit in m/s^2 (e.g. m/s^2, g, counts:m/s^2).")
    return found[0]


def imported_readings(session, stream: str, trim: float = 0.0,
                      still: StillOptions | None = None) -> StillReadings:
    """The accelerometer rows of every still pose of an imported recording (`static_readings`);
    `still`: the detector settings, channels "acc" unless given."""
    still = still or StillOptions()
    still = dataclasses.replace(still, channels=still.channels or "acc")
    return static_readings(session, stream, trim=trim, still=still)
