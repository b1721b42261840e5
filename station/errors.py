"""Every error the station raises for something a person can act on, under one base.

Each message names the problem and what to do about it. The command line prints it as one line on
stderr and exits with the class's `exit_code` (docs/cli.md: 0 ok, 1 failed, 2 bad input, 3 device,
130 interrupted); `station --verbose` adds the traceback. Each class keeps the built-in base that
callers already catch (ValueError for bad input, RuntimeError for a bench that misbehaved)::

    StationError                          1  the base; `except StationError` catches them all
     +-- InputError (ValueError)          2  a file, an option or data the station cannot use
     |    +-- CalibrationInputError       2  the data cannot determine the calibration
     |    +-- SessionFormatError          2  not a session file this software can read
     |    +-- CalibrationFileError        2  a calibration file this software must not use
     |    +-- UnwatchedCampaignError      2  an unattended campaign on devices without a watchdog
     +-- MissingFileError (FileNotFoundError)  2  a file named on the command line is not there
     +-- SessionLockedError (RuntimeError)     1  another live process is writing the session file
     +-- SessionUncheckedError (RuntimeError)  1  a session file's check did not finish: no verdict
     +-- AcquisitionError (RuntimeError)  3  the bench did not do what the session needs
     |    +-- RecordingError              3  the IMU stream stopped
     |    +-- ProtocolError               3  the bench did not behave as the protocol needs
     |         +-- SessionPaused          3  the operator stopped; the session can be resumed
     |         +-- FlaggedWindow          3  a window the live check flags: recorded again
     |         +-- RedoLimitError         3  a position still flagged after its redo_limit redos
     |         +-- SoakError              3  a thermal soak did not settle
     |              +-- SoakTimeout       3  the unit still warmed or cooled at the soak's timeout
     +-- SuspectFitError                1  a fit inconsistent with its noise: not written as good
     +-- OperatorAbort                  1  the operator ended the session
     +-- RecordStoreError (RuntimeError)  1  the calibration record store cannot be read or written
          +-- NewerStoreError             1  a record store made by a newer station: upgrade

Device errors have their own root, `drivers.errors.DeviceError` (exit code 3), because the drivers
never import the station (the layering contracts in pyproject.toml): ProfileError (ValueError, exit
code 2), LinkError (ConnectionError: SerialPortError, DeviceLostError, CanBusError) and TableError
(RuntimeError: TableTimeout, TableBusy, TableFault, TableLinkError,
TableReplyError) and ChamberError (RuntimeError: ChamberTimeout, ChamberLinkError,
ChamberReplyError, ChamberAlarm, ChamberDoorOpen; ChamberRangeError is also a ValueError, exit code
2). The command line catches both roots.
"""


class StationError(Exception):
    """Base of the station's errors; `exit_code` is what the command line exits with."""

    exit_code = 1


class InputError(StationError, ValueError):
    """A file, an option or data the station cannot use; the message says what to give instead."""

    exit_code = 2


class CalibrationInputError(InputError):
    """The data cannot determine the calibration; the message says what to do about it.

    Attributes
    ----------
    advice : str
        What the operator should do (more positions, another orientation, a wrong unit, ...).
    """

    def __init__(self, problem: str, advice: str):
        super().__init__(f"{problem} {advice}")
        self.problem = problem
        self.advice = advice


class SessionFormatError(InputError):
    """The file is not a session file this software can read; the message says what was found."""


class CalibrationFileError(InputError):
    """A calibration file this software cannot or must not use; the message says what to do."""


class UnwatchedCampaignError(InputError):
    """An unattended campaign (a thermal campaign) whose table or chamber register map has no
    communication watchdog: a killed or hung station would leave them running
    (station.acquire.watchdog); `--no-watchdog` records anyway."""


class MissingFileError(StationError, FileNotFoundError):
    """A file named on the command line does not exist (or is not a regular file)."""

    exit_code = 2


class SessionLockedError(StationError, RuntimeError):
    """Another live process is writing the session file."""


class SessionUncheckedError(StationError, RuntimeError):
    """The structure check of a session file (station.session.check) could not finish: out
    of CPU time, stopped from outside, or hung. No verdict on the file: it was not found damaged
    (that is a SessionFormatError); the message says how to go on."""


class AcquisitionError(StationError, RuntimeError):
    """The bench did not do what the session needs; the message says what to check."""

    exit_code = 3


class RecordingError(AcquisitionError):
    """The IMU stream stopped: the device went silent or the reader failed."""


class ProtocolError(AcquisitionError):
    """The bench did not behave as the protocol needs; the message says what and what to do."""


class SessionPaused(ProtocolError):
    """The table stopped answering and the operator chose to stop; the session can be resumed."""


class FlaggedWindow(ProtocolError):
    """A window the protocol saw go wrong while recording it (the table moved during a static
    window, its rate left the tolerance while rotating): the protocol records the position again
    (station.protocols.redo) instead of ending the session. `flag` says what was wrong."""

    def __init__(self, flag: str):
        super().__init__(flag)
        self.flag = flag


class RedoLimitError(ProtocolError):
    """A position's window was still flagged after the bench profile's `redo_limit` redos
    (station.protocols.redo); the message names the position, the flag and what to do."""


class SuspectFitError(StationError):
    """The fit disagrees with the noise of its readings (station.solve.quality): the calibration
    is not written as good; the message says why and what to look at."""


class OperatorAbort(StationError):
    """The operator ended the session (end of input, or 'no' to a question that must be 'yes')."""


class RecordStoreError(StationError, RuntimeError):
    """The calibration record store (station.records) cannot be opened, read or written: an
    unreachable server, a locked or damaged file, a full disk; the message names the store and
    what to do."""


class NewerStoreError(RecordStoreError):
    """The record store's schema version is newer than this station knows: made by a newer
    station; upgrade this one (it never writes to a schema it does not know)."""


class SoakError(ProtocolError):
    """A thermal soak did not bring the unit to a steady temperature (station.protocols.thermal);
    the message names the setpoint, what was seen and what to do."""


class SoakTimeout(SoakError):
    """The unit's own temperature still changed faster than the stability threshold when the
    soak's timeout ran out."""
