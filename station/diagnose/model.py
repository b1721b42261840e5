"""A model of a rotary session: the nominal calibration plus a set of extensions, fitted jointly.

The joint fit alternates (block coordinate descent on the likelihood):
1. each extension is fitted to the residuals of the twin without it (station.diagnose.effects);
2. the measured series is corrected by what the extensions add to the nominal twin, reduced with
   Eq. (18) and calibrated again (`station.calibrate`: closed form + maximum likelihood, weighted by
   the noise from the static windows). Extensions that are part of the calibration's own model
   (`calibration_options`: rate_error, the random magnitudes) are not corrected for; their options
   go to `station.calibrate` instead.
The deviance of a model is the chi2 of its binned residuals plus the rail pile-up deviance
(station.diagnose.rails) plus the extensions' random-effect terms (`Fitted.penalty`); the
difference between two nested models is their likelihood ratio.
"""

from dataclasses import dataclass

import numpy as np

from station.diagnose import linear, rails
from station.diagnose import prediction as twin
from station.diagnose.effects import EXTENSIONS, Fitted
from station.files.jsonable import jsonable
from station.solve.calibrate import CalibrationResult, calibrate


@dataclass(frozen=True)
class Model:
    """A fitted model: calibration, extensions {name: Fitted} in the order added, the twin's
    context and biases, and its deviance's parts."""

    calibration: CalibrationResult
    fitted: dict
    ctx: twin.Context
    b: np.ndarray
    chi2: float
    rails: float

    @property
    def twin(self) -> twin.Twin:
        """The twin of the model, made again on each call (its (n, k) arrays are of the
        session's size over m, and several models are held at once: the steps, the best
        candidate, the one being fitted); its series are made a chunk at a time."""
        return twin.predict(self.ctx, self.fitted, EXTENSIONS, self.b)

    @property
    def names(self) -> tuple:
        return tuple(self.fitted)

    @property
    def deviance(self) -> float:
        return self.chi2 + self.rails + sum(f.penalty for f in self.fitted.values())

    @property
    def dof(self) -> int:
        """Parameters of the extensions."""
        return sum(f.dof for f in self.fitted.values())


def noise(data, clipped: bool = False) -> np.ndarray:
    """(m, n) standard error of the readings M; with a clipped output, an entry whose rotating
    window sat on the rail a fraction f of the time has 1 - f of the information."""
    sigma = data.sigma_m
    if clipped:
        r0, rail = data.windows["rotating"][0], data.rail
        f = np.array([(np.abs(data.counts[j, r0:stop]) == rail).mean(0)
                      for j, stop in enumerate(data.rot_stop)]).T
        sigma = sigma / np.sqrt(np.maximum(1 - f, 1e-6))
    return sigma


def readings(data, ctx: twin.Context, fitted: dict) -> tuple:
    """(M, sigma, options): the Eq. (18) readings corrected by what the extensions `fitted` add
    to the twin of `ctx` (except those the calibration models itself), their standard error and
    the options of station.calibrate."""
    inside, options = _in_calibration(fitted)
    full, bare = (twin.predict(ctx, f, EXTENSIONS) for f in (fitted, inside))
    added = np.concatenate([data.reduce(full.part(rows).z - bare.part(rows).z, rows).M
                            for rows in data.chunks()], axis=1)
    return data.reduced.M - added, noise(data, "saturation" in fitted), options


def evaluate(data, calibration: CalibrationResult, fitted: dict) -> Model:
    """The Model of a calibration and fitted extensions: twin output and deviance, in one pass
    over the positions (the rail pile-up expected from each chunk's output before it is made
    the residual)."""
    ctx = twin.context(data, calibration.a, calibration.v, data.sigma)
    tw = twin.predict(ctx, fitted, EXTENSIONS)
    clipped, expected = "saturation" in fitted, []

    def residual(rows):
        part = tw.part(rows)
        expected.append(rails.expected(data, part.mu, data.sigma, clipped,
                                       data.rail_offsets(part.mu, rows)))
        return data.residual(part.z, rows)  # in z, which may be mu: read before

    chi2 = linear.chi2(data, linear.centred_signature(data, residual), data.sigma)
    return Model(calibration, dict(fitted), ctx, tw.b, chi2,
                 rails.deviance(rails.observed(data), sum(expected)))


def nominal(data) -> Model:
    """The nominal model: Eq. (18) readings calibrated, no extension."""
    return evaluate(data, calibrate(data.reduced.M, data.c, sigma=noise(data)), {})


def fit(data, names, start: Model, iterations: int = 3) -> Model:
    """Jointly fit the extensions `names` (in that order) with the calibration, from `start`."""
    cal, fitted = start.calibration, dict(start.fitted)
    for _ in range(iterations):
        ctx = twin.context(data, cal.a, cal.v, data.sigma)
        for name in names:
            fitted[name] = _fit_one(ctx, fitted, name)
        fitted = {name: fitted[name] for name in names}
        m_corrected, sigma, options = readings(data, ctx, fitted)
        cal = calibrate(m_corrected, data.c, sigma=sigma, **options)
    return evaluate(data, cal, fitted)


def _fit_one(ctx: twin.Context, fitted: dict, name: str):
    """The extension `name` fitted to the residuals of the twin with the other `fitted` ones,
    given as their centred bins and static means (station.diagnose.linear), made a chunk of
    positions at a time."""
    others = twin.predict(ctx, {k: f for k, f in fitted.items() if k != name}, EXTENSIONS)
    return EXTENSIONS[name].fit(ctx, others, linear.centred_signature(ctx.data, others.residual))


def _in_calibration(fitted: dict) -> tuple[dict, dict]:
    """The extensions that the calibration models itself ({name: Fitted}) and their options for
    station.calibrate; the readings are corrected for the other extensions only."""
    inside, options = {}, {}
    for name, f in fitted.items():
        own = getattr(EXTENSIONS[name], "calibration_options", None)
        own_options = None if own is None else own(f)
        if own_options is not None:
            inside[name] = f
            options.update(own_options)
    return inside, options


def parameters(f: Fitted) -> dict:
    """JSON-ready {parameter: {"value", "sigma", "unit"}} of a fitted extension ("unit" only
    where the extension states one)."""
    return jsonable({k: {"value": np.asarray(v, float),
                         "sigma": np.asarray(f.sigma.get(k, np.nan), float),
                         **({"unit": f.units[k]} if k in f.units else {})}
                     for k, v in f.values.items()})
