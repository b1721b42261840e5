"""The solver of still poses (right-angle iron, free static), the biases estimated with it."""

from station.solve.calibrate import calibrate


def calibrate_still(readings, gravity: float, nominal=None, method: str = "auto",
                    refine: bool = True, *, names=None):
    """`station.calibrate` of still poses (`station.reduce.still.StillReadings`: M, sigma and
    `constraints()`) with the biases estimated and the poses' constraints
    (`readings.constraints()`): the ellipsoid (triad) or Hwangbo & Kanade's factorization
    (Eqs. 14-15 and 29), or a fallback start (`result.start`), then maximum likelihood weighted by
    each mean's standard error plus the per-pose term it estimates (`result.pose_sigma`; the
    sigmas are the total figure, `*_sigma_white` the white-noise one). names: the channels' names
    for the refusals (which parameter the poses leave undetermined)."""
    return calibrate(readings.M, gravity, d=3, bias="estimate", constraints=readings.constraints(),
                     sigma=readings.sigma, nominal=nominal, method=method, refine=refine,
                     names=names)
