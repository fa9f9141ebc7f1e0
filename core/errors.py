"""Errors that are the user's to fix: printed by the CLI as one ``error:`` line (exit code 2),
never as a traceback. Library code and plugins raise them from here (never importing the CLI).

* :class:`UserError`: a mistake in what the user gave (a path, a name, an option value);
* :class:`CheckpointError`, :class:`StorageError` (both re-exported by :mod:`mocap.checkpoint`),
  :class:`~mocap.spec.SpecError`, :class:`~mocap.motion.clip.MotionDataError`,
  :class:`~mocap.plugins.PluginError`, :class:`StageFailed` (re-exported by :mod:`mocap.pipeline`):
  the same contract for checkpoints, writes, specs, motion files, plugins and stages
  (:func:`user_errors` lists them).

This module imports no torch, so that naming these types (a failing ``mocap validate``) stays fast.
"""

from __future__ import annotations

import errno
from pathlib import Path


class UserError(Exception):
    """An error in what the user gave us: printed as one clear message, exit code 2, no traceback."""


class StageFailed(Exception):
    """A stage could not run (bad checkpoint path, trainer error that is the user's to fix)."""


class CheckpointError(ValueError):
    """A checkpoint that cannot be used as asked: the message names the file and what to do."""


class StorageError(OSError):
    """Writing a file failed (disk full, read-only or unwritable folder); the message names the file.

    An :class:`OSError` (``errno`` is the cause's) whose ``str`` is the whole user-facing message.
    """

    def __init__(self, path: Path | str, cause: OSError, *, previous_kept: bool = False):
        super().__init__(cause.errno, cause.strerror or str(cause), str(path))
        self.path = Path(path)
        if cause.errno in DISK_FULL:
            what = "the disk is full (no space left on device)" if cause.errno == errno.ENOSPC else "the disk quota is exceeded"
            hint = "free some space and run the same command again (a run resumes from its last checkpoint)"
        elif cause.errno in (errno.EACCES, errno.EPERM, errno.EROFS):
            what = f"the folder is not writable ({cause.strerror or cause})"
            hint = "choose a writable location"
        else:
            what = cause.strerror or str(cause)
            hint = "check the disk and run the same command again"
        kept = f"; the previous {self.path.name} is unchanged" if previous_kept else ""
        self.message = f"cannot write {self.path}: {what}{kept}; {hint}"

    def __str__(self) -> str:
        return self.message


DISK_FULL = frozenset(e for e in (errno.ENOSPC, getattr(errno, "EDQUOT", None)) if e is not None)


def user_errors() -> tuple[type[BaseException], ...]:
    """Exception types that are the user's input, not a bug (printed without a traceback)."""
    from mocap.motion.clip import MotionDataError
    from mocap.plugins import PluginError
    from mocap.spec import SpecError

    return (UserError, SpecError, PluginError, MotionDataError, StageFailed, CheckpointError, StorageError)


__all__ = ["CheckpointError", "StageFailed", "StorageError", "UserError", "user_errors"]
