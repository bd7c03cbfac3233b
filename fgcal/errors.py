"""Exceptions for user mistakes: the CLI turns these into one-line messages."""


class FgcalError(ValueError):
    """A problem with the user's input (file, option, data), reported without a traceback."""


class DatasetError(FgcalError):
    """A dataset directory or one of its files is malformed.

    The message always names the file and, where it applies, the row (1-based, header = row 1)
    or the pose id.
    """


class ModelError(FgcalError):
    """A robot model file or a model name is malformed or unknown."""
