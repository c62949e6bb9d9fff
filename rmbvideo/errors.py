"""User-facing errors: the CLI prints their message as one line on stderr and exits non-zero."""


class RmbvideoError(Exception):
    """Base class for errors caused by the user's input or environment, not by a bug."""


class InputError(RmbvideoError):
    """An input file is missing, unreadable or malformed. The message names the file."""


class OutputError(RmbvideoError):
    """An output cannot be written (unwritable folder, full disk). The message names the path."""


class ModelError(RmbvideoError):
    """A model file is corrupt, foreign, unsafe, or does not match the code or the input."""


class OptionError(RmbvideoError):
    """An option has a value the method or command cannot take. The message names the option."""
