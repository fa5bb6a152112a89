"""The one exception family of scanqa.

Every error a user can cause is a :class:`ScanQAError`; its message names the file,
the field, the value and the fix. The CLI prints ``scanqa: <message>`` and exits
non-zero without a traceback.
"""

from __future__ import annotations


class ScanQAError(Exception):
    """Base class of every error scanqa raises on bad input or impossible requests."""


class ConfigError(ScanQAError):
    """A scanner config (TOML) is missing a key, has an unknown key or a bad value."""


class InputError(ScanQAError):
    """An input file or array is unreadable, inconsistent or degenerate."""


class RangeError(ScanQAError):
    """A request lies outside the range a model or table covers."""


class OutputError(ScanQAError):
    """An output cannot be written: a folder in the way, a read-only or full disk."""


class MethodError(ConfigError, ValueError):
    """A name that no mapping holds: a reading, form or floor of the model, a decision.

    Also a :class:`ValueError`, which it replaced, so callers that caught that still do.
    """
