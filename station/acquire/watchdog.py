"""The devices' watchdogs from the station's side (drivers.heartbeat: what they are).

`fed(device)`: while a session or campaign holds the rotary table or the thermal chamber, its
driver writes the watchdog's heartbeat (`device.heartbeat`); a beat that cannot be written is a
device error delivered to the session (`station.acquire.interrupts.deliver`: the protocol's next
poll raises it, as any lost device), withdrawn if the device is released before that.

`require_watchdogs(bench, allowed)`: an unattended campaign (a thermal campaign: hours with nobody
at the bench) is refused before it starts when its table or chamber has no watchdog in its
register map, unless the technician says `--no-watchdog` (`allowed`).
"""

import contextlib

from station.errors import UnwatchedCampaignError


@contextlib.contextmanager
def fed(device):
    """`device.heartbeat` while entered, its failures delivered to the session (module doc)."""
    from station.acquire import interrupts

    told = []

    def failed(error: BaseException) -> None:
        told.append(error)
        interrupts.deliver(error)

    with device.heartbeat(failed):
        try:
            yield device
        finally:
            for error in told:
                interrupts.withdraw(error)


def missing_watchdogs(bench) -> list:
    """The watchdog sections the campaign's devices lack ("[table.watchdog] of <profile>")."""
    missing = []
    if bench.table_map is not None and bench.table_map.watchdog is None:
        missing.append(f"[table.watchdog] (the table's register map {bench.table_source})")
    if bench.chamber is not None and bench.chamber.register_map.watchdog is None:
        missing.append("[chamber.watchdog] (the chamber's register map, [chamber] profile)")
    return missing


def require_watchdogs(bench, allowed: bool) -> None:
    """Refuse (UnwatchedCampaignError, exit 2) an unattended campaign on `bench` whose devices
    lack a watchdog, unless `allowed` (`--no-watchdog`)."""
    missing = missing_watchdogs(bench)
    if missing and not allowed:
        raise UnwatchedCampaignError(
            f"{bench.source}: a thermal campaign runs unattended, but its profile has no "
            f"{' and no '.join(missing)}: a killed or hung station would leave the devices "
            "running. Use register maps with a watchdog (docs/devices.md \"Watchdog\"), or give "
            "--no-watchdog to record anyway")
