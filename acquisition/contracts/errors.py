"""The root of micam's input errors: what the command line and the worker report as bad input.

micam tells two kinds of failure apart, and treats them differently everywhere:

- **Input errors** (`UserError` and its subclasses): the options, a file, a session, a
  message or the machine's state are not what they must be, and the message says what to
  fix. The command line prints it on one line and exits 2; the worker fails the job for
  good (another attempt would read the same input).
- **Everything else is a bug in micam**: the command line exits 70 and writes the traceback
  to a bug log it names; the worker logs the traceback and marks the job retryable.

Each layer has its own input-error type below this root, raised where that layer finds
the input wrong: `ConfigError` and `DaemonError` (the service), `SessionError` (the session
store), `DescriptionError` (a rig and array description), `CalibrationInputError` (the
calibration and imaging), `SimulationInputError` (the simulated world). Code never turns a
`ValueError` into an input error by catching it: a `ValueError` from the math is a bug.
The driver layer (`daq`) sits below this root; its `ConfigurationError` is reported where
the application opens the boards.
"""


class UserError(Exception):
    """A problem the user can fix (bad option, file or session); printed plainly."""
