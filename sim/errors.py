"""The simulated world's input error: options that describe no world it can simulate.

A subclass of `acquisition.contracts.errors.UserError` (the root of micam's input errors), so
`micam simulate` reports it as bad options (exit 2); anything else the world raises is a bug.
"""

from acquisition.contracts.errors import UserError


class SimulationInputError(UserError):
    """The options ask for a world that cannot be simulated (the message says which and why)."""
