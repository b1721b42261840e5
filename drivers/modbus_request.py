"""One Modbus transaction with bounded retries, its failures turned into a device family's errors.

Shared by the Modbus drivers whose error classes follow one pattern (`Failures`): a device that
does not answer (`timeout`), a link refused or lost (`link`: the client reconnects on the next
try), a reply that does not answer the request (`reply`: fewer registers than asked, garbled),
'device busy' (Modbus exception 6, retried after `busy_backoff` s) and the rest (`base`, with the
exception code in words). A timeout, a lost link or a bad reply is retried only where `repeat` says
the request is safe to send again; a busy answer always (the controller did nothing).

pymodbus reports a timeout as a ModbusIOException whose text holds "No response"; any other
ModbusIOException is a reply it could not decode (e.g. a byte count beyond the frame). An RTU
frame with a bad CRC is dropped by pymodbus' framer unseen: it ends as no reply, a timeout.
"""

import logging
import time
from dataclasses import dataclass

from pymodbus.constants import ExcCodes
from pymodbus.exceptions import ConnectionException, ModbusIOException

log = logging.getLogger(__name__)


@dataclass(frozen=True)
class Failures:
    """A device family's error classes (each a subclass of `base`); `busy` (exception 6 after
    the retries) and `fault` (exception 4, device failure) default to `base`."""

    base: type
    timeout: type
    link: type
    reply: type
    busy: type | None = None
    fault: type | None = None


def link_words(exc: OSError | ConnectionException) -> str:
    """What a lost or refused TCP connection means, in words an operator can act on."""
    if isinstance(exc, ConnectionResetError):
        return "connection reset by the controller (is it powered? did it restart?)"
    if isinstance(exc, ConnectionRefusedError):
        return "connection refused (is the controller running, and the port right?)"
    if isinstance(exc, BrokenPipeError | ConnectionAbortedError):
        return "connection broken by the controller (is it powered? did it restart?)"
    if isinstance(exc, ConnectionException) and "failed to connect" in str(exc).lower():
        # pymodbus' words when the client could not (re)connect
        return "cannot connect (is the controller running and powered, the port right?)"
    if isinstance(exc, ConnectionException):
        return "connection lost (is it powered? did its controller restart?)"
    return f"network error ({exc.strerror or exc}); check its power, cable and IP address"


def exception_name(code: int) -> str:
    """pymodbus' name of a Modbus exception code in words ("illegal address"), or "unknown
    exception" for a code outside the standard."""
    try:
        return ExcCodes(code).name.lower().replace("_", " ")
    except ValueError:
        return "unknown exception"


def read_registers(client, first: int, count: int, device_id: int, where: str, reply: type):
    """One read of `count` holding registers; a reply with fewer or more is refused with `reply`
    (a pymodbus error response is returned as it is, for `request` to judge)."""
    response = client.read_holding_registers(first, count=count, device_id=device_id)
    if not response.isError() and len(response.registers) != count:
        raise reply(f"{where}: short reply, {len(response.registers)} registers of the {count} "
                    "asked; check the register map (docs/devices.md) and the controller's "
                    "firmware")
    return response


def request(call, what: str, where: str, failures: Failures, *, client, device_id: int,
            retries: int, timeout: float, link_words, repeat: bool = True,
            busy_backoff: float = 0.05):
    """Run `call()` (one pymodbus request) and return its response, or raise one of `failures`.

    where      : the device in words for messages ("thermal chamber at host:port")
    what       : the request in words ("read state")
    link_words : exception -> what a lost link means, in words an operator can act on
    """
    error, busy = None, False
    for attempt in range(retries + 1):
        if attempt and not repeat and not busy:
            break
        busy = False
        try:
            response = call()
        except ModbusIOException as exc:
            if "No response" in str(exc):
                error = failures.timeout(f"{where}: no reply to {what} within {timeout} s "
                                         f"({attempt + 1} tries); check the cable, its power "
                                         f"and the device id {device_id}")
            else:
                error = failures.reply(f"{where}: garbled reply to {what} ({exc}); check the "
                                       f"register map, the line settings and the device id "
                                       f"{device_id}")
            continue
        except (OSError, ConnectionException) as exc:
            client.close()  # the next try reconnects
            error = failures.link(f"{where}: {link_words(exc)} during {what}")
            error.__cause__ = exc
            continue
        except failures.reply as exc:
            error = exc
            continue
        if not response.isError():
            if attempt:
                log.info("%s: %s answered after %d retries", what, where, attempt)
            return response
        code = response.exception_code
        if code == ExcCodes.DEVICE_BUSY:
            error = (failures.busy or failures.base)(
                f"{where}: stayed busy (Modbus exception 6) during {what} after {attempt + 1} "
                "tries; wait for it to finish and retry")
            busy = True
            time.sleep(busy_backoff)
            continue
        if code == ExcCodes.DEVICE_FAILURE and failures.fault is not None:
            raise failures.fault(f"{where}: reports a device failure (Modbus exception 4) to "
                                 f"{what}; check its fault display and reset it")
        raise failures.base(f"{where}: answered {what} with Modbus exception {code} "
                            f"({exception_name(code)}); check the register map and device id "
                            "in the device profile, and the controller's display")
    raise error
