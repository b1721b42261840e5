"""The manifest of a thermal campaign: one rotary session per chamber setpoint
(docs/session-format.md, "Thermal campaign").

A campaign is a directory holding `campaign.json` and the session files `soak_<k>_<K>K.h5`
(k from 1, the setpoint rounded to whole kelvin). The manifest is JSON, rewritten atomically (a
temporary file renamed into place) after every step, so a killed station leaves either the old
or the new one:

    {"format": "station-thermal-campaign", "version": 1, "unit_serial": "SN42",
     "profile": "/abs/bench.toml", "created": "...", "setpoints": [263.15, ...],
     "soaks": [{"setpoint": 263.15, "file": "soak_1_263K.h5", "state": "done",
                "unit_temperature": 263.4, "rate_K_per_min": 0.03, "soak_seconds": 412.0}, ...]}

`state` is "pending" (nothing done), "soaked" (the soak converged; the session may be partial)
or "done" (the session recorded). Every value is checked on load: the file is untrusted input.
"""

import json
import math
import os
from dataclasses import dataclass
from pathlib import Path

from station.errors import InputError
from station.files.jsonable import jsonable
from station.files.provenance import utc_now
from station.limits import json_loads

FORMAT = "station-thermal-campaign"
VERSION = 1
NAME = "campaign.json"
STATES = ("pending", "soaked", "done")
MAX_SOAKS = 64
"""More setpoints than any chamber campaign has: a larger list is refused as corrupt."""


class CampaignError(InputError):
    """A campaign manifest that is missing, malformed or inconsistent."""


def soak_file(k: int, setpoint: float) -> str:
    """The session file name of soak k (0-based) at `setpoint` K."""
    return f"soak_{k + 1}_{round(setpoint)}K.h5"


def manifest_path(path) -> Path:
    """The manifest of a campaign given by its directory or its manifest file."""
    path = Path(path)
    return path / NAME if path.is_dir() else path


def is_campaign(path) -> bool:
    """True when `path` is a campaign directory or its manifest (a session file is not)."""
    path = Path(path)
    return (path / NAME).is_file() if path.is_dir() else path.name == NAME


@dataclass
class Campaign:
    """A campaign manifest in memory; `save` writes it. `directory` holds its files."""

    directory: Path
    unit_serial: str
    profile: str
    setpoints: list
    soaks: list
    created: str

    @classmethod
    def create(cls, directory, unit_serial: str, profile: str, setpoints) -> "Campaign":
        """A new campaign in `directory` (created; refused if it holds a manifest already)."""
        directory = Path(directory)
        if (directory / NAME).exists():
            raise CampaignError(f"{directory} holds a campaign already; continue it with "
                                f"`station resume {directory}` or choose another --out")
        directory.mkdir(parents=True, exist_ok=True)
        soaks = [{"setpoint": float(t), "file": soak_file(k, t), "state": "pending"}
                 for k, t in enumerate(setpoints)]
        campaign = cls(directory, unit_serial, str(Path(profile).resolve()),
                       [float(t) for t in setpoints], soaks, utc_now())
        campaign.save()
        return campaign

    @classmethod
    def load(cls, path) -> "Campaign":
        """The campaign of a directory or manifest path, checked (CampaignError names the
        problem)."""
        path = manifest_path(path)
        try:
            doc = json_loads(path.read_text(encoding="utf-8"), "it", error=CampaignError)
        except FileNotFoundError:
            raise CampaignError(f"{path}: no campaign manifest; give the directory `station "
                                "record` wrote a thermal campaign into") from None
        except (OSError, UnicodeDecodeError, CampaignError) as exc:
            raise CampaignError(f"{path}: cannot read the campaign manifest ({exc}); it is "
                                "written atomically, so it was changed by hand or the disk "
                                "failed: restore it from the session files' metadata") from None
        return cls(path.parent, *_checked(doc, path))

    def save(self) -> None:
        """Write the manifest atomically (a temporary file renamed into place)."""
        doc = {"format": FORMAT, "version": VERSION, "unit_serial": self.unit_serial,
               "profile": self.profile, "created": self.created, "setpoints": self.setpoints,
               "soaks": self.soaks}
        path = self.directory / NAME
        tmp = path.with_name(f"{NAME}.tmp{os.getpid()}")
        tmp.write_text(json.dumps(jsonable(doc), indent=2) + "\n", encoding="utf-8")
        os.replace(tmp, path)

    def next_soak(self) -> int | None:
        """Index of the first soak not done, None when all are."""
        return next((k for k, s in enumerate(self.soaks) if s["state"] != "done"), None)

    def update(self, k: int, **fields) -> None:
        """Record `fields` (state, unit_temperature, ...) for soak k and save."""
        self.soaks[k].update(jsonable(fields))
        self.save()

    def done(self) -> list:
        """(setpoint, session path) of the soaks done, in order."""
        return [(s["setpoint"], self.directory / s["file"]) for s in self.soaks
                if s["state"] == "done"]


def _checked(doc, path) -> tuple:
    """(unit_serial, profile, setpoints, soaks, created) of a manifest document, every value
    checked."""
    def bad(what: str):
        return CampaignError(f"{path}: {what}; the manifest is not one `station record` wrote")

    if not isinstance(doc, dict) or doc.get("format") != FORMAT:
        raise bad(f"format is not {FORMAT!r}")
    if doc.get("version") != VERSION:
        raise bad(f"version {doc.get('version')!r} is not {VERSION}")
    strings = [doc.get(k) for k in ("unit_serial", "profile", "created")]
    if not all(isinstance(s, str) for s in strings):
        raise bad("unit_serial, profile and created must be strings")
    setpoints, soaks = doc.get("setpoints"), doc.get("soaks")
    if not (isinstance(setpoints, list) and isinstance(soaks, list)
            and 0 < len(setpoints) == len(soaks) <= MAX_SOAKS):
        raise bad(f"setpoints and soaks must be lists of the same length 1..{MAX_SOAKS}")
    for k, (t, s) in enumerate(zip(setpoints, soaks, strict=True)):
        if not (isinstance(t, int | float) and math.isfinite(t) and isinstance(s, dict)
                and s.get("setpoint") == t and s.get("state") in STATES
                and s.get("file") == soak_file(k, t)):
            raise bad(f"soak {k + 1} does not match its setpoint, state or file name")
    return strings[0], strings[1], [float(t) for t in setpoints], soaks, strings[2]
