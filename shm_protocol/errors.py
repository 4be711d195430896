"""The exceptions of the shared-memory protocol.

Every failure a caller can act on has its own class; all of them derive from
:class:`ShmError`, so a caller that only wants "the daemon link is broken" catches that.
Each message says what was expected, what was found, and what to do.
"""

from __future__ import annotations


class ShmError(Exception):
    """Base class of every error raised by :mod:`shm_protocol`.

    Subclasses keep their extra attributes optional so that they survive pickling (a
    worker process of a vector env re-raises them in the parent).
    """


class InvalidNameError(ShmError, ValueError):
    """A segment name that cannot be used (contains ``/``, too long, odd characters)."""


class SegmentNotFoundError(ShmError, FileNotFoundError):
    """The named segment does not exist in ``/dev/shm``.

    :ivar name: the segment name looked for.
    :ivar available: descriptions of the plausible segments that do exist.
    """

    def __init__(self, message: str, name: str = "", available: list[str] | None = None) -> None:
        super().__init__(message)
        self.name = name
        self.available = list(available or [])

    def __str__(self) -> str:  # FileNotFoundError would otherwise format errno/filename
        return str(self.args[0])


class LayoutError(ShmError, ValueError):
    """A segment or an array does not have the expected size, shape, dtype or trailer."""


class SegmentBusyError(ShmError):
    """The segment already has a live writer, and this writer was asked to be the only one
    (``FrameWriter(..., create=False, exclusive=True)``: an env attaching to a daemon slot
    another env is using).

    A writer that is gone does not count: one that closed (shutting-down flag set), or whose
    process died (re-attaching after a crash works).

    :ivar name: the segment name.
    :ivar pid: the live writer's pid (may be this process's own).
    :ivar command: that process's command line, shortened ("" when unknown).
    """

    def __init__(self, message: str, name: str = "", pid: int = 0, command: str = "") -> None:
        super().__init__(message)
        self.name = name
        self.pid = pid
        self.command = command


class NonFiniteError(ShmError, ValueError):
    """A float frame passed to ``publish`` holds NaN or infinite values."""


class FrameTimeoutError(ShmError, TimeoutError):
    """No new frame arrived within the timeout while the writer still looked alive.

    :ivar name: the segment name.
    :ivar timeout: the timeout in seconds.
    """

    def __init__(self, message: str, name: str = "", timeout: float = 0.0) -> None:
        super().__init__(message)
        self.name = name
        self.timeout = timeout

    def __str__(self) -> str:
        return str(self.args[0])


class WriterGoneError(ShmError):
    """The segment's writer is gone: its process died, its heartbeat went stale, or it
    closed the segment in an orderly way (shutting-down flag).

    Not final: once a new writer attaches to the same name, the same reader receives its
    frames again.

    :ivar name: the segment name.
    :ivar pid: the writer pid recorded in the trailer.
    :ivar reason: ``"exited"``, ``"stale"`` or ``"shutdown"``.
    """

    def __init__(self, message: str, name: str = "", pid: int = 0, reason: str = "") -> None:
        super().__init__(message)
        self.name = name
        self.pid = pid
        self.reason = reason


__all__ = [
    "FrameTimeoutError",
    "InvalidNameError",
    "LayoutError",
    "NonFiniteError",
    "SegmentBusyError",
    "SegmentNotFoundError",
    "ShmError",
    "WriterGoneError",
]
