"""Errors that are the user's to fix: printed by the CLI as one ``error:`` line (exit code 2),
never as a traceback. Library code and plugins raise them from here (never importing the CLI).

* :class:`UserError`: a mistake in what the user gave (a path, a name, an option value);
* :class:`~mocap.checkpoint.CheckpointError`, :class:`~mocap.checkpoint.StorageError`,
  :class:`~mocap.spec.SpecError`, :class:`~mocap.motion.clip.MotionDataError`,
  :class:`~mocap.plugins.PluginError`, :class:`~mocap.pipeline.StageFailed`: the same contract for
  checkpoints, writes, specs, motion files, plugins and stages (:func:`user_errors` lists them).
"""

from __future__ import annotations


class UserError(Exception):
    """An error in what the user gave us: printed as one clear message, exit code 2, no traceback."""


def user_errors() -> tuple[type[BaseException], ...]:
    """Exception types that are the user's input, not a bug (printed without a traceback)."""
    from mocap.checkpoint import CheckpointError, StorageError
    from mocap.motion.clip import MotionDataError
    from mocap.pipeline import StageFailed
    from mocap.plugins import PluginError
    from mocap.spec import SpecError

    return (UserError, SpecError, PluginError, MotionDataError, StageFailed, CheckpointError, StorageError)


__all__ = ["UserError", "user_errors"]
