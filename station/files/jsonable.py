"""The one numpy -> JSON adapter: every JSON the station writes (summaries, truth files, events,
diagnosis documents) passes its values through `jsonable`.

JSON has no NaN or infinity (strict parsers refuse them), so non-finite numbers become null: a
sigma that is unknown, an unbounded range, a statistic that does not apply.
"""

import math

import numpy as np


def jsonable(obj):
    """JSON-ready copy of obj: dict keys to str, tuples and arrays to lists, numpy scalars to
    Python numbers and booleans, NaN and +-inf to None; anything else as it is."""
    if isinstance(obj, dict):
        return {str(k): jsonable(v) for k, v in obj.items()}
    if isinstance(obj, np.ndarray):
        return jsonable(obj.tolist())
    if isinstance(obj, list | tuple):
        return [jsonable(v) for v in obj]
    if isinstance(obj, np.generic):
        obj = obj.item()
    if isinstance(obj, float) and not math.isfinite(obj):
        return None
    return obj
