"""Exceptions for problems a user can fix (the CLI prints them without a traceback)."""

__all__ = ["BusyError", "DiskFullError", "NanoctError", "StoreError"]


class NanoctError(Exception):
    """A problem with the user's input or files; the message says what to do."""


class StoreError(NanoctError):
    """A data-set store is missing, damaged or does not match the request."""


class BusyError(NanoctError):
    """Another process is writing the same reconstruction or training run (it holds the lock file)."""


class DiskFullError(NanoctError, OSError):
    """A write failed for want of disk space; the message names the path and the space needed."""

    def __str__(self) -> str:
        return str(self.strerror)
