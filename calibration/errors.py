"""The calibration's input error: a session, file or option it cannot calibrate from.

Every error the calibration and the acoustic imaging raise because of their input derives
from `CalibrationInputError` (itself an `acquisition.contracts.errors.UserError`, the root of
micam's input errors). Anything else they raise is a bug (see that module's docstring).
"""

from acquisition.contracts.errors import UserError


class CalibrationInputError(UserError):
    """The session or a file given with it cannot be calibrated or imaged as it is."""
