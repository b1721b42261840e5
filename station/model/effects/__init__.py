"""Named effects of the simulator, one module each, all off by default (docs/simulator.md).

Each module holds a frozen dataclass of explicit parameters and a pure `apply` function of the
truth time series and those parameters. `parse("rate_error=scale=0.01,spread=0.002")` builds the
parameters from the command-line form NAME[=key=value[,key=value...]]; per-sensor values are
separated by colons (`latency=delay=0:0.001:0.002`).
"""

import dataclasses

import numpy as np

from station.model.effects.axis_wobble import AxisWobble
from station.model.effects.bias_drift import BiasDrift
from station.model.effects.earth_rate import EarthRate
from station.model.effects.g_sensitivity import GSensitivity
from station.model.effects.latency import Latency
from station.model.effects.outliers import Outliers
from station.model.effects.polynomial import Polynomial
from station.model.effects.rate_error import RateError
from station.model.effects.saturation import Saturation
from station.model.effects.scale_asymmetry import ScaleAsymmetry
from station.model.effects.scale_nonlinearity import ScaleNonlinearity

EFFECTS = {
    "bias_drift": BiasDrift,
    "scale_nonlinearity": ScaleNonlinearity,
    "scale_asymmetry": ScaleAsymmetry,
    "polynomial": Polynomial,
    "rate_error": RateError,
    "earth_rate": EarthRate,
    "g_sensitivity": GSensitivity,
    "saturation": Saturation,
    "axis_wobble": AxisWobble,
    "latency": Latency,
    "outliers": Outliers,
}
"""Effect name -> parameter dataclass. `none` means no effect."""
SIZE = {"bias_drift": ("warmup", "heating"), "scale_nonlinearity": ("k2",),
        "scale_asymmetry": ("k",), "polynomial": ("c2", "c3", "c4", "c5"),
        "rate_error": ("scale", "spread"), "g_sensitivity": ("matrix",),
        "axis_wobble": ("angle_deg",), "latency": ("delay",),
        "outliers": ("rate", "size")}
"""The parameters that give an effect its size: all zero (their defaults), it changes nothing.
`earth_rate` and `saturation` act with their defaults (the Earth's rate, the unit's range)."""


def _value(text: str):
    """A float, or a tuple of floats for colon-separated per-sensor values, or None."""
    if text.lower() == "none":
        return None
    parts = text.split(":")
    try:
        values = tuple(float(x) for x in parts)
    except ValueError:
        raise ValueError(
            f"effect parameter value {text!r} is not a number (use e.g. 0.01 or "
            "0.01:0.02 for per-sensor values)"
        ) from None
    return values[0] if len(values) == 1 else values


def parse(spec: str) -> tuple[str, object | None]:
    """(name, parameters) from NAME[=key=value,...]; parameters is None for `none`."""
    name, _, rest = spec.partition("=")
    name = name.strip()
    if name == "none":
        return name, None
    if name not in EFFECTS:
        raise ValueError(f"unknown effect {name!r}; choose from none, {', '.join(EFFECTS)}")
    cls = EFFECTS[name]
    fields = {f.name for f in dataclasses.fields(cls)}
    kwargs = {}
    for item in filter(None, rest.split(",")):
        key, eq, text = item.partition("=")
        if not eq or key not in fields:
            raise ValueError(
                f"effect {name}: bad parameter {item!r}; expected key=value with key "
                f"in {', '.join(sorted(fields))}"
            )
        kwargs[key] = _value(text)
    params = cls(**kwargs)
    if name in SIZE and not any(np.any(np.asarray(getattr(params, f), float))
                                for f in SIZE[name]):
        raise ValueError(f"effect {name} with {', '.join(SIZE[name])} = 0 changes nothing; give "
                         f"its size, e.g. --effect {name}={SIZE[name][0]}=<value>")
    return name, params


def parse_all(specs) -> dict:
    """{name: parameters} for a list of specs; a name given twice is an error."""
    out = {}
    for spec in specs or ():
        name, params = parse(spec)
        if name in out:
            raise ValueError(f"effect {name} given twice; give all its parameters in one --effect")
        if params is not None:
            out[name] = params
    return out


def to_json(effects: dict) -> dict:
    """{name: {param: value}} for the truth file."""
    return {name: dataclasses.asdict(p) for name, p in effects.items()}


def from_json(doc: dict) -> dict:
    """{name: parameters} from the form of `to_json` (as read back from JSON: per-sensor lists
    become tuples again)."""
    out = {}
    for name, params in doc.items():
        if name not in EFFECTS:
            raise ValueError(f"unknown effect {name!r}; choose from {', '.join(EFFECTS)}")
        out[name] = EFFECTS[name](**{k: tuple(v) if isinstance(v, list) else v
                                     for k, v in params.items()})
    return out
