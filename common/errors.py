"""One family of user-facing errors.

Every failure a user can cause (a missing file, a stream that is not ours, no
face in view) raises a subclass of :class:`FdError`. The command-line tools
print its message as one line on stderr and exit non-zero; anything else is a
bug and keeps its traceback.
"""


class FdError(Exception):
    """A failure the user can act on; its message is one line."""


class InputError(FdError):
    """The input file or device cannot be used (missing, unreadable, not a video)."""


class NoFaceError(FdError):
    """No face was found where one was needed."""


class BitstreamError(FdError):
    """The bitstream is not ours, is corrupted, or breaks the format."""
