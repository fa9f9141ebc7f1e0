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

    def log(self, step: int, **metrics: float) -> None:
        if not self.enabled:
            return
        record = {"stage": self.stage, "step": int(step), "time": round(time.time(), 3)}
        for key, value in metrics.items():
            value = float(value)
            record[key] = value if math.isfinite(value) else None
        with self.path.open("a", encoding="utf-8") as fh:
            fh.write(json.dumps(record) + "\n")
        writer = self._writer()
        if writer is not None:
            for key, value in metrics.items():
                if math.isfinite(float(value)):
                    writer.add_scalar(f"{self.stage}/{key}", float(value), int(step))

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

    def close(self) -> None:
        if self._tb is not None:
            self._tb.close()
            self._tb = None
