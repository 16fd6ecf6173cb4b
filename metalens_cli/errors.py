"""Typed errors raised by the core; the CLI turns them into one line and exit code 2 (1 for
:class:`ResultFailed`)."""


class MetalensError(Exception):
    """Base class of every error the package raises on purpose."""


class InputError(MetalensError, ValueError):
    """A value given by the user is malformed or out of range.

    A ``ValueError``; the CLI prints it as one line and exits 2. Its text is
    ``"{field}: {message} (expected {expected})"``.

    Attributes:
        field: the option or TOML key path (or the parameter) that holds the value.
        message: what is wrong with it.
        expected: the accepted form, or None.

    Examples:
        >>> str(InputError("--wavelength", "'450' has no unit", "a length with a unit, e.g. 450nm"))
        "--wavelength: '450' has no unit (expected a length with a unit, e.g. 450nm)"
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
    """The input was valid but the computation could not produce a trustworthy result.

    E.g. two images with too few consistent feature matches to register; the CLI exits 1, not 2
    (an :class:`InputError`'s code).

    Args:
        *args: the message, as for any exception.
    """


class Terminated(BaseException):
    """SIGTERM received (raised by the CLI's handler): unwinds like Ctrl-C, so outputs in progress
    are removed and training writes a checkpoint, and the CLI exits 143."""
