"""What every resumable trainer does around its loop, written once (PPO, distill, VMP's supervised,
and the composite trainers that run those as sub-phases: PMCP and ``vmp_track``).

* :func:`begin` — the stage's torch threads, its working directory, and the process RNGs (torch,
  numpy, ``random``) seeded from ``ctx.seed``; returns the checkpoint path and the device;
* :func:`resume_from` — the trainer's own checkpoint when there is one (format checked: another
  file in its place is a :class:`~mocap.errors.CheckpointError` naming it), else None after
  dropping ``metrics.jsonl`` rows of a run that crashed before its first checkpoint;
* :func:`resume_state_file` — a composite trainer's JSON record of its phases (PMCP), format
  checked the same way;
* :func:`resumed` — after the trainer restored its own state: the process RNG state, the log
  truncated to the checkpoint's step (rows logged after it would be doubled), one console line.
"""

from __future__ import annotations

import json
import random
from pathlib import Path
from typing import Any

import numpy as np
import torch

from mocap.checkpoint import load_checkpoint
from mocap.errors import CheckpointError
from mocap.rng import set_rng_state


def begin(ctx: Any, torch_threads: int | None, checkpoint_name: str) -> tuple[Path, torch.device]:
    """Threads, working directory and seeds of a stage; ``(checkpoint path, device)``."""
    if torch_threads is not None:
        torch.set_num_threads(torch_threads)
    workdir = Path(ctx.workdir)
    workdir.mkdir(parents=True, exist_ok=True)
    torch.manual_seed(ctx.seed)
    np.random.seed(ctx.seed % 2**32)
    random.seed(ctx.seed)
    return workdir / checkpoint_name, torch.device(ctx.device)


def resume_from(ctx: Any, path: Path, fmt: str, what: str, map_location: Any = None) -> dict[str, Any] | None:
    """The trainer's checkpoint at ``path`` (its ``format`` must be ``fmt``; ``what`` names the
    trainer in the error), or None for a fresh start, after dropping this stage's stale log rows."""
    if not path.is_file():
        ctx.log.truncate_after(0)  # rows of a run that crashed before its first checkpoint
        return None
    ck = load_checkpoint(path, map_location=map_location)
    if ck.get("format") != fmt:
        raise CheckpointError(f"{path}: not a {what} checkpoint (format {ck.get('format')!r}); remove it to start the stage over")
    return ck


def resume_state_file(path: Path, fmt: Any, what: str) -> dict[str, Any] | None:
    """The JSON state file at ``path`` (its ``format`` must be ``fmt``), or None when there is none.
    A file that is not JSON or not this trainer's is a :class:`~mocap.errors.CheckpointError` naming it."""
    if not path.is_file():
        return None
    try:
        state = json.loads(path.read_text(encoding="utf-8"))
    except (OSError, UnicodeDecodeError, json.JSONDecodeError) as exc:
        raise CheckpointError(f"{path}: not a {what} state file ({exc}); remove it to start the stage over") from None
    if not isinstance(state, dict) or state.get("format") != fmt:
        found = state.get("format") if isinstance(state, dict) else type(state).__name__
        raise CheckpointError(f"{path}: not a {what} state file (format {found!r}); remove it to start the stage over")
    return state


def resumed(ctx: Any, what: str, step: int, rng: Any = None, detail: str = "") -> None:
    """Finish a resume at ``step``: restore the process RNGs (``rng``, when the checkpoint holds this
    process's), drop the log rows after ``step``, say so."""
    if rng is not None:
        set_rng_state(rng)
    ctx.log.truncate_after(step)
    ctx.console.print(f"{what}: resuming at {detail or f'step {step}'}")


__all__ = ["begin", "resume_from", "resume_state_file", "resumed"]
