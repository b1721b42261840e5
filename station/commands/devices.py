"""`station devices`: the serial ports and CAN interfaces this computer offers.

Serial ports come from pyserial (`serial.tools.list_ports`); CAN channels from python-can
(`can.detect_available_configs`), which asks every interface backend it knows (a few seconds;
`--can-interfaces` limits the search). Put a port or channel into a bench profile's `[imu]` section
(see `station record --help`).
"""

import argparse
import json
import logging
import warnings


def register(p) -> None:
    """The options, description and examples of this subcommand, on its parser `p`."""
    p.description = __doc__
    p.epilog = (
        "examples:\n  station devices\n  station devices --can-interfaces socketcan,virtual"
        " --json"
    )
    p.add_argument("--can-interfaces", type=_names, metavar="NAMES",
                   help="comma-separated python-can interfaces to probe (default: all it knows)")
    p.add_argument("--json", action="store_true", help="machine-readable output")
    p.set_defaults(run=run)


def run(args) -> int:
    found = list_devices(args.can_interfaces)
    if args.json:
        print(json.dumps(found, indent=2))
        return 0
    print("serial ports:" if found["serial"] else "serial ports: none found")
    for port in found["serial"]:
        print(f"  {port['device']}  {port['description']}  ({port['hwid']})")
    print("CAN channels:" if found["can"] else "CAN channels: none found")
    for config in found["can"]:
        print(f"  interface {config['interface']!r}, channel {config['channel']!r}")
    return 0


def list_devices(can_interfaces=None) -> dict:
    """{"serial": [{device, description, hwid}], "can": [{interface, channel}]}."""
    import can
    from serial.tools import list_ports

    serial = [{"device": p.device, "description": p.description, "hwid": p.hwid}
              for p in sorted(list_ports.comports(), key=lambda p: p.device)]
    logger = logging.getLogger("can")
    level = logger.level
    logger.setLevel(logging.CRITICAL)  # backends without their vendor library log warnings
    try:
        with warnings.catch_warnings():
            warnings.simplefilter("ignore")
            configs = can.detect_available_configs(interfaces=can_interfaces)
    finally:
        logger.setLevel(level)
    found = [{"interface": str(c.get("interface")), "channel": str(c.get("channel"))}
             for c in configs]
    return {"serial": serial, "can": found}


def _names(text: str) -> list:
    import can

    names = [n.strip() for n in text.split(",") if n.strip()]
    unknown = sorted(set(names) - set(can.VALID_INTERFACES))
    if not names or unknown:
        raise argparse.ArgumentTypeError(
            f"unknown CAN interfaces {unknown}; python-can knows {sorted(can.VALID_INTERFACES)}")
    return names
