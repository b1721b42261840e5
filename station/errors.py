"""Errors raised for inputs the calibration cannot use, each with advice on what to do."""


class CalibrationInputError(ValueError):
    """The data cannot determine the calibration; the message says what to do about it.

    Attributes
    ----------
    advice : str
        What the operator should do (more positions, another orientation, a wrong unit, ...).
    """

    def __init__(self, problem: str, advice: str):
        super().__init__(f"{problem} {advice}")
        self.problem = problem
        self.advice = advice
