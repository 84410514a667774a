"""Input checks that raise short, specific ``ValueError`` messages before any work."""
from __future__ import annotations

import numpy as np

__all__ = ["as_finite_array", "named_message", "Terminated"]


class Terminated(KeyboardInterrupt):
    """SIGTERM, raised in the main thread as Ctrl-C is: the same clean-up runs (``finally`` blocks, pools stopped).

    A subclass of :class:`KeyboardInterrupt`, so every path that stops work on Ctrl-C stops it on
    SIGTERM too; the command line tells them apart by the exit status (130 for SIGINT, 143 for SIGTERM).
    """


def named_message(name: str, error, *, aliases: tuple = (), empty: str | None = None) -> str:
    """One line naming the argument ``name``: ``"mjcf: x is not ..."`` -> ``"--mjcf: x is not ..."``.

    ``error`` is an exception or a message. Its first line is kept, without a leading ``name:``,
    ``name`` without its dashes, or any of ``aliases``; an ``OSError``'s file name is added when the
    message lacks it. An empty message becomes ``empty`` (default: the exception's type name).
    """
    text = str(error).strip()
    fallback = empty if empty is not None else (type(error).__name__ if isinstance(error, BaseException) else "")
    msg = text.splitlines()[0] if text else fallback
    if isinstance(error, OSError) and error.filename and str(error.filename) not in msg:
        msg = f"{msg}: {error.filename}"
    for prefix in (name, name.lstrip("-"), *aliases):
        if msg.startswith(f"{prefix}: "):
            msg = msg[len(prefix) + 2:]
    return f"{name}: {msg}"


def as_finite_array(name: str, value, shape: tuple | None = None, ndim: int | None = None) -> np.ndarray:
    """Return ``value`` as a float array, checking shape and finiteness.

    ``shape`` may contain ``None`` for a free dimension, e.g. ``(None, 3)``.
    """
    try:
        arr = np.asarray(value, dtype=float)
    except (TypeError, ValueError):
        raise ValueError(f"{name}: expected a numeric array, got {type(value).__name__}") from None
    if ndim is not None and arr.ndim != ndim:
        raise ValueError(f"{name}: expected a {ndim}-D array, got shape {arr.shape}")
    if shape is not None:
        ok = arr.ndim == len(shape) and all(s is None or s == a for s, a in zip(shape, arr.shape))
        if not ok:
            want = "(" + ", ".join("N" if s is None else str(s) for s in shape) + ")"
            raise ValueError(f"{name}: expected shape {want}, got {arr.shape}")
    if not np.all(np.isfinite(arr)):
        bad = int(np.size(arr) - np.count_nonzero(np.isfinite(arr)))
        raise ValueError(f"{name}: expected finite values, got {bad} NaN/inf entries")
    return arr
