"""The one exception type users see: a clear message, turned into a non-zero exit by the CLI."""


class NeoError(Exception):
    """Bad input or an unrecoverable condition, with a message meant for the user."""

    exit_code: int = 2
    """The CLI's exit status for it: 2 (bad input, an error); a subclass for a command
    that ran but found nothing says 1."""


class DataError(NeoError):
    """A dataset on disk is malformed (missing field, missing image, bad pose, ...)."""


class SpecError(NeoError):
    """A scene specification (simulation) is malformed; the message names the field."""


class NeoWarning(UserWarning):
    """Something the user should know that does not stop the work (frames skipped, a cache
    that cannot be written, a pre-shrunk folder that is not used); ``neo`` prints it as one
    ``warning:`` line."""


class MissingFramesWarning(NeoWarning):
    """Frames whose image file is missing were skipped (``--skip-missing``)."""
