"""Exception classes shared by every layer.

The split matters to orchestration: an :class:`InputError` means the user must change something
(a file, a frame, a field) and retrying is pointless; a :class:`TransientError` may go away on
retry (a busy lock, a flaky mount). Flows retry only the latter.
"""


class ArtiTwinError(Exception):
    """Base class of every error ArtiTwin raises on purpose."""


class InputError(ArtiTwinError, ValueError):
    """Bad input the user must fix. The message names the file, frame or field and what to do."""


class TransientError(ArtiTwinError):
    """A failure that may succeed when retried (lock contention, an interrupted transfer)."""
