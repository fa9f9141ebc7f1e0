"""Run logs: ``metrics.jsonl`` (one JSON object per logged step) and TensorBoard events."""

from __future__ import annotations

import json
import math
import time
from pathlib import Path
from typing import Any


class MetricsLogger:
    """Appends ``{"stage", "step", "time", **metrics}`` lines to ``metrics.jsonl``; mirrors scalars to TensorBoard.

    On resume, :meth:`truncate_after` drops lines logged after the checkpoint's step so that a
    run interrupted between a log write and a checkpoint never shows a step twice.

    ``enabled=False`` makes it write nothing (the default, None, enables it only on the main
    process of a data-parallel run, :func:`mocap.distributed.is_main`).
    """

    def __init__(self, path: Path, stage: str, tensorboard_dir: Path | None = None, *, enabled: bool | None = None):
        from mocap.distributed import is_main

        self.path = Path(path)
        self.stage = stage
        self.enabled = is_main() if enabled is None else bool(enabled)
        if self.enabled:
            self.path.parent.mkdir(parents=True, exist_ok=True)
        self._tb_dir = tensorboard_dir
        self._tb: Any = None

    def child(self, name: str) -> "MetricsLogger":
        """A logger for a sub-phase of this stage: the same ``metrics.jsonl`` and TensorBoard folder,
        stage label ``<stage>/<name>`` (so a resumed phase truncates only its own rows). Close it
        when the phase ends."""
        return MetricsLogger(self.path, f"{self.stage}/{name}", self._tb_dir, enabled=self.enabled)

    def log(self, step: int, **metrics: float) -> None:
        if not self.enabled:
            return
        record = {"stage": self.stage, "step": int(step), "time": round(time.time(), 3)}
        for key, value in metrics.items():
            value = float(value)
            record[key] = value if math.isfinite(value) else None
        from mocap.checkpoint import StorageError

        try:
            with self.path.open("a", encoding="utf-8") as fh:
                fh.write(json.dumps(record) + "\n")
        except OSError as exc:  # a full disk, a read-only folder: one error line naming the file
            raise StorageError(self.path, exc) from None
        try:
            writer = self._writer()
            if writer is not None:
                for key, value in metrics.items():
                    if math.isfinite(float(value)):
                        writer.add_scalar(f"{self.stage}/{key}", float(value), int(step))
        except OSError as exc:  # TensorBoard's writer (its thread re-raises a failed write here)
            tb_dir = self._tb_dir
            self._drop_tensorboard()
            raise StorageError(tb_dir or self.path, exc) from None

    def _writer(self) -> Any:
        if not self.enabled:
            return None
        if self._tb is None and self._tb_dir is not None:
            from torch.utils.tensorboard import SummaryWriter

            self._tb = SummaryWriter(str(self._tb_dir))
        return self._tb

    def records(self) -> list[dict[str, Any]]:
        if not self.path.is_file():
            return []
        out = []
        for line in self.path.read_text(encoding="utf-8").splitlines():
            try:
                out.append(json.loads(line))
            except json.JSONDecodeError:  # a line cut by a crash
                continue
        return out

    def truncate_after(self, step: int) -> None:
        """Keep only this stage's records with ``step <= step`` (and every other stage's)."""
        from mocap.checkpoint import atomic_write_text

        if not self.enabled:
            return
        kept = [r for r in self.records() if r.get("stage") != self.stage or r.get("step", 0) <= step]
        atomic_write_text(self.path, "".join(json.dumps(r) + "\n" for r in kept))

    def _drop_tensorboard(self) -> None:
        tb, self._tb, self._tb_dir = self._tb, None, None
        if tb is not None:
            try:
                tb.close()
            except Exception:  # noqa: BLE001 - already failing (full disk): the first error is the one reported
                pass

    def close(self) -> None:
        """Flush and close TensorBoard; best effort (a write error was already raised by :meth:`log`)."""
        self._drop_tensorboard()
