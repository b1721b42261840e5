"""Device adapters (serial IMU, CAN IMU, Modbus rotary table) and their virtual twins.

Every IMU driver satisfies one declared interface, `ImuDriver`, with one meaning per verb:

    open()              connect to the device (or reconnect after a loss); a no-op when connected
    close()             disconnect; a later open() starts afresh
    read_block(timeout) the samples decoded since the last call, waiting up to `timeout` seconds
                        of the driver's clock for the first: a SampleBlock, or None if none
                        came. Raises the link's ConnectionError once the device is lost, after
                        every sample decoded before the loss has been handed out; open() then
                        reconnects
    stats               the link's counters (a `LinkStats`), cumulative over reconnects

and is a context manager (open on enter, close on exit). `open_imu(link, address, profile, clock)`
builds and opens the driver of a link from a lazy table (python-can's BACKENDS style), so
importing `drivers` loads neither pyserial, python-can nor pymavlink.
"""

import importlib
from dataclasses import dataclass
from typing import Protocol, runtime_checkable

from drivers.errors import ProfileError

LINKS = {
    "serial": ("drivers.serial_imu", "SerialImu"),
    "can": ("drivers.can_imu", "CanImu"),
    "mavlink": ("drivers.mavlink_imu", "MavlinkImu"),
}
"""IMU link name -> (module, driver class), imported only when the link is used."""


@dataclass
class LinkStats:
    """Counters every IMU link keeps, cumulative over reconnects.

    samples    : samples decoded and handed out
    gaps       : places where the sequence number jumped forward (one or more samples missing)
    dropped    : sequence numbers missing in those gaps (samples lost on the way or destroyed)
    duplicates : samples received twice (same sequence number, same payload), dropped
    restarts   : places where the device restarted its numbering (a reset): new segments
    """

    samples: int = 0
    gaps: int = 0
    dropped: int = 0
    duplicates: int = 0
    restarts: int = 0


@runtime_checkable
class ImuDriver(Protocol):
    """What the station asks of an IMU driver (the verbs are described in the module docstring)."""

    @property
    def stats(self) -> LinkStats: ...

    def open(self) -> "ImuDriver": ...

    def close(self) -> None: ...

    def read_block(self, timeout: float = 0.1): ...

    def __enter__(self) -> "ImuDriver": ...

    def __exit__(self, *exc) -> None: ...


def driver_class(link: str) -> type:
    """The driver class of `link` ("serial", "can" or "mavlink"), imported on first use;
    ProfileError naming the links for any other name."""
    try:
        module, name = LINKS[link]
    except KeyError:
        raise ProfileError(f"unknown IMU link {link!r}; known links: {', '.join(LINKS)}") from None
    return getattr(importlib.import_module(module), name)


def open_imu(link: str, address, profile, clock=None, **options) -> ImuDriver:
    """The driver of `link`, opened (use it as a context manager to close it).

    address : serial: a port path or pyserial URL; can: the `can.Bus` keyword arguments (dict);
              mavlink: a port path or pyserial URL, or `udpin:HOST:PORT`
    profile : the driver's device profile (object, path or bundled name)
    options : driver-specific keywords (serial `read_timeout`, can `log_path`)
    """
    return driver_class(link)(address, profile, clock, **options).open()
