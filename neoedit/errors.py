"""The one exception type users see: a clear message, turned into a non-zero exit by the CLI."""


class NeoError(Exception):
    """Bad input or an unrecoverable condition, with a message meant for the user."""


class DataError(NeoError):
    """A dataset on disk is malformed (missing field, missing image, bad pose, ...)."""


class SpecError(NeoError):
    """A scene specification (simulation) is malformed; the message names the field."""
