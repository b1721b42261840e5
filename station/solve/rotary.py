"""The solver of a rotary session's Eq. (18) readings (the static means subtracted: no bias)."""

from station.solve.calibrate import calibrate


def calibrate_rotary(reduced, rate: float, nominal=None, method: str = "auto",
                     refine: bool = True):
    """`station.calibrate` of Eq. (18) readings (`station.reduce.eq18.Reduced`: M and sigma) with
    the table rate as the magnitude: the closed form, then maximum likelihood weighted by each
    reading's standard error; in the frame of `nominal` when given."""
    return calibrate(reduced.M, rate, sigma=reduced.sigma, nominal=nominal, method=method,
                     refine=refine)
