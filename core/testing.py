"""Helpers for testing mocap plugins in isolation (also used by mocap's own tests).

Example, in a plugin's test suite::

    from mocap.testing import invoke, use_plugins
    import my_plugin

    def test_my_task_validates(tmp_path):
        with use_plugins(("my_plugin", my_plugin)):
            result = invoke(["validate", "spec.yaml"])
        assert result.exit_code == 0, result.stderr

``use_plugins`` registers the given plugin objects through the same loader as installed
entry-point plugins (so hook typos, duplicate names and registration errors behave exactly as
they will for users), optionally without the installed ones.
"""

from __future__ import annotations

import contextlib
import io
from dataclasses import dataclass
from typing import Iterator

from mocap.conformance import ContractViolation, check_latent_space, check_simulator, check_task, fake_sim_state
from mocap.plugins import PluginSet, get_plugins, load_plugins, set_plugins


@contextlib.contextmanager
def use_plugins(*plugins: tuple[str, object], entry_points: bool = True) -> Iterator[PluginSet]:
    """Make ``(name, plugin)`` pairs (plus the installed plugins unless ``entry_points=False``)
    the process-wide plugin set for the duration of the block."""
    previous = get_plugins()
    pset = load_plugins(plugins, entry_points=entry_points)
    set_plugins(pset)
    try:
        yield pset
    finally:
        set_plugins(previous)


@dataclass
class Result:
    exit_code: int
    stdout: str
    stderr: str

    @property
    def output(self) -> str:
        return self.stdout + self.stderr


def invoke(args: list[str]) -> Result:
    """Run the ``mocap`` CLI in-process with the current plugin set; capture exit code and output."""
    from mocap.cli import main

    out, err = io.StringIO(), io.StringIO()
    with contextlib.redirect_stdout(out), contextlib.redirect_stderr(err):
        code = main([str(a) for a in args])
    return Result(code, out.getvalue(), err.getvalue())


__all__ = [
    "ContractViolation",
    "Result",
    "check_latent_space",
    "check_simulator",
    "check_task",
    "fake_sim_state",
    "invoke",
    "use_plugins",
]
