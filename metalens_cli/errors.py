"""Typed errors raised by the core; the CLI turns them into one line and exit code 2 (1 for
:class:`ResultFailed`)."""


class MetalensError(Exception):
    """Base class of every error the package raises on purpose."""


class InputError(MetalensError, ValueError):
    """A value given by the user is malformed or out of range.

    ``field`` names the option or TOML key path, ``expected`` the accepted form.
    """

    def __init__(self, field: str, message: str, expected: str | None = None):
        self.field = field
        self.message = message
        self.expected = expected
        text = f"{field}: {message}"
        if expected:
            text += f" (expected {expected})"
        super().__init__(text)


class SamplingError(InputError):
    """A simulation grid cannot represent the field without aliasing or wrap-around: bad input
    (``field`` names the lens parameter that would fix it). ``forceable``: the caller may
    compute anyway (``force=True``; ``psf-scan --force``), at the cost of aliasing."""

    def __init__(self, field: str, message: str, expected: str, forceable: bool = False):
        super().__init__(field, message, expected)
        self.forceable = forceable


class ResultFailed(MetalensError):
    """The input was valid but the computation could not produce a trustworthy result (e.g. two
    images with too few consistent feature matches to register); the CLI exits 1, not 2."""


class Terminated(BaseException):
    """SIGTERM received (raised by the CLI's handler): unwinds like Ctrl-C, so outputs in progress
    are removed and training writes a checkpoint, and the CLI exits 143."""
