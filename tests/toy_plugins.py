"""Throw-away plugins for the tests: registered through the same loader as installed plugins."""

from __future__ import annotations

import os
import signal
from pathlib import Path
from typing import Any

from pydantic import BaseModel, ConfigDict, Field

from mocap.checkpoint import load_checkpoint, save_checkpoint
from mocap.hooks import hookimpl
from mocap.interfaces import MotionSource, StageResult, Trainer


class Optim(BaseModel):
    model_config = ConfigDict(extra="forbid")
    lr: float = 1e-3
    schedule: str = "constant"


class ToyModelParams(BaseModel):
    model_config = ConfigDict(extra="forbid")
    hidden: int = Field(8, ge=1)
    optim: Optim = Field(default_factory=Optim)
    files: list[Path] = Field(default_factory=list)


class CountParams(BaseModel):
    model_config = ConfigDict(extra="forbid")
    iterations: int = Field(5, ge=1)
    stop_after: int | None = None  # simulate Ctrl-C after this many iterations


class CountTrainer(Trainer):
    """Counts iterations, checkpointing each one; resumes from its checkpoint."""

    calls: list[str] = []

    def __init__(self, params: CountParams):
        self.params = params

    def run(self, ctx) -> StageResult:
        CountTrainer.calls.append(ctx.stage)
        path = Path(ctx.workdir) / "checkpoint.pt"
        start = load_checkpoint(path)["iteration"] if path.is_file() else 0
        done_now = 0
        for it in range(start, self.params.iterations):
            ctx.log.log(it + 1, value=float(it))
            save_checkpoint(path, {"iteration": it + 1, "upstream": sorted(ctx.upstream)}, spec_yaml=ctx.spec_yaml())
            done_now += 1
            if self.params.stop_after is not None and done_now >= self.params.stop_after:
                os.kill(os.getpid(), signal.SIGINT)  # the user presses Ctrl-C
            if ctx.should_stop():
                break
        ctx.publish(f"{ctx.stage}_count.txt").write_text(str(load_checkpoint(path)["iteration"]))
        return StageResult(checkpoint=path, metrics={"iterations": float(load_checkpoint(path)["iteration"])})


class ToyComponent:
    def __init__(self, params: ToyModelParams | None = None, **kwargs):
        self.params = params
        self.kwargs = kwargs


class ToyMotions(MotionSource):
    """A motion source that reads no files (the pipeline only fingerprints its inputs)."""

    def __init__(self, **kwargs: Any):
        self.kwargs = kwargs

    def load(self, skeleton: Any) -> Any:
        raise NotImplementedError("the toy pipeline never loads motions")


class toy:  # a plugin object (pluggy accepts any object with hookimpl-marked attributes)
    @staticmethod
    @hookimpl
    def register_humanoids(register):
        register("toy_body", ToyComponent, params=ToyModelParams, description="a toy humanoid")

    @staticmethod
    @hookimpl
    def register_motion_sources(register):
        register("toy_motions", ToyMotions, description="no params")

    @staticmethod
    @hookimpl
    def register_simulators(register):
        register("toy_sim", ToyComponent, params=ToyModelParams)

    @staticmethod
    @hookimpl
    def register_imitators(register):
        register("toy_imitator", ToyComponent, params=ToyModelParams)

    @staticmethod
    @hookimpl
    def register_latent_spaces(register):
        register("toy_latent", ToyComponent, params=ToyModelParams)
        register("toy_latent_b", ToyComponent, params=ToyModelParams)

    @staticmethod
    @hookimpl
    def register_trainers(register):
        register("count", CountTrainer, params=CountParams)


TOY_SPEC = """\
spec_version: 1
name: toy
humanoid: {name: toy_body}
motions: {name: toy_motions}
simulator: {name: toy_sim, params: {hidden: 4}}
imitator:
  name: toy_imitator
  params: {hidden: 16, optim: {lr: 0.01}}
  trainer: {name: count, params: {iterations: 3}}
latent:
  name: toy_latent
  trainer: {name: count, params: {iterations: 2}}
"""
