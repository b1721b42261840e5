"""The solver of still poses (right-angle iron, free static), the biases estimated with it."""

from station.solve.calibrate import calibrate


def calibrate_still(readings, gravity: float, nominal=None, method: str = "auto",
                    refine: bool = True):
    """`station.calibrate` of still poses (`station.reduce.still.StillReadings`: M, sigma and
    `constraints()`) with the biases estimated and the poses' constraints
    (`readings.constraints()`): the ellipsoid (triad) or Hwangbo & Kanade's factorization
    (Eqs. 14-15 and 29), then maximum likelihood weighted by each mean's standard error."""
    return calibrate(readings.M, gravity, d=3, bias="estimate", constraints=readings.constraints(),
                     sigma=readings.sigma, nominal=nominal, method=method, refine=refine)
