"""The drivers' errors, under one root (the drivers never import the station, so this is their own).

    DeviceError                         exit code 3 on the command line
     +-- ProfileError (ValueError)      2  a device profile that cannot describe the device
     +-- LinkError (ConnectionError)    3  the link to an IMU cannot be opened or was lost
     |    +-- SerialPortError              a serial port; `port` names it
     |    |    +-- DeviceLostError         the device stopped answering mid-stream (unplugged)
     |    +-- CanBusError                  a CAN bus; `channel` names it
     |    +-- MavlinkError                 a MAVLink link, or no IMU message on it; `address`
     +-- TableError (RuntimeError)      3  the rotary table did not do what was asked
          +-- TableTimeout                 no reply within the timeout, after the bounded retries
          +-- TableBusy                    'device busy' (Modbus exception 6) after the retries
          +-- TableFault                   a device failure (Modbus exception 4): needs the operator
          +-- TableLinkError               the TCP connection was refused, reset or broken
          +-- TableReplyError              a reply that does not answer the request (short, garbled)
     +-- ChamberError (RuntimeError)    3  the thermal chamber did not do what was asked
          +-- ChamberTimeout               no reply within the timeout, after the bounded retries
          +-- ChamberLinkError             the TCP connection or serial port was refused or lost
          +-- ChamberReplyError            a reply that does not answer the request (short, garbled)
          +-- ChamberAlarm                 the chamber's alarm bit is set: it needs the operator
          +-- ChamberDoorOpen              the chamber's door is open
          +-- ChamberRangeError (ValueError) 2 a setpoint or ramp outside the profile's limits
     +-- TwinError (RuntimeError)       1  a virtual device (drivers.twins) stopped on an error of
                                           its own: the simulation failed, not a device

The station's own errors are drawn in `station.errors`; the command line catches both roots.
"""


class DeviceError(Exception):
    """Base of the drivers' errors; `exit_code` is what the command line exits with."""

    exit_code = 3


class ProfileError(DeviceError, ValueError):
    """A device profile that cannot describe the device; the message names the file, key and fix."""

    exit_code = 2


class LinkError(DeviceError, ConnectionError):
    """The link to an IMU cannot be opened or was lost; the message says what to check."""


class SerialPortError(LinkError):
    """The serial port cannot be opened or was lost; `port` names it."""

    def __init__(self, port: str, message: str):
        super().__init__(message)
        self.port = port


class DeviceLostError(SerialPortError):
    """The device stopped answering mid-stream (unplugged, powered off)."""


class TableError(DeviceError, RuntimeError):
    """The rotary table did not do what was asked; the message says what to check."""


class TableTimeout(TableError):
    """No reply from the table within the timeout, after the bounded retries."""


class TableBusy(TableError):
    """The table kept answering 'device busy' (Modbus exception 6) after the bounded retries."""


class TableFault(TableError):
    """The table reported a device failure (Modbus exception 4): it needs the operator."""


class TableLinkError(TableError):
    """The TCP connection to the table was refused, reset or broken (controller off, restarted)."""


class TableReplyError(TableError):
    """The table's reply does not answer the request: fewer registers than asked, or garbled."""


class ChamberError(DeviceError, RuntimeError):
    """The thermal chamber did not do what was asked; the message says what to check."""


class ChamberTimeout(ChamberError):
    """No reply from the chamber within the timeout, after the bounded retries."""


class ChamberLinkError(ChamberError):
    """The link to the chamber was refused or lost (TCP connection, serial port)."""


class ChamberReplyError(ChamberError):
    """The chamber's reply does not answer the request: fewer registers than asked, garbled, or a
    value that is no temperature."""


class ChamberAlarm(ChamberError):
    """The chamber reports an alarm (its status bit): it needs the operator."""


class ChamberDoorOpen(ChamberError):
    """The chamber reports its door open: it cannot hold a temperature."""


class ChamberRangeError(ChamberError, ValueError):
    """A setpoint or ramp rate outside the limits the chamber's profile allows; nothing was sent."""

    exit_code = 2


class TwinError(DeviceError, RuntimeError):
    """A virtual device stopped on an error of its own (`drivers.twins.failure`): the message
    names the twin and the error, its cause is the error."""

    exit_code = 1


class CanBusError(LinkError):
    """The CAN bus cannot be opened or was lost; `channel` names it."""

    def __init__(self, channel: str, message: str):
        super().__init__(message)
        self.channel = channel


class MavlinkError(LinkError):
    """A MAVLink link cannot be opened or brings no IMU message; `address` names it."""

    def __init__(self, address: str, message: str):
        super().__init__(message)
        self.address = address
