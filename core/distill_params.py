"""The distill trainer's parameters (:class:`DistillParams`) and DAgger's β schedule they feed
(:func:`mixture_beta`). The trainer is in :mod:`mocap.distill`, which re-exports both."""

from __future__ import annotations

import math
from pathlib import Path
from typing import Literal

from pydantic import BaseModel, ConfigDict, Field, model_validator

from mocap.bounds import EnvCount, LearningRate, ThreadCount
from mocap.fail_state_params import FailStateParams, GetUpStartParams, check_getup_starts


# ---------------------------------------------------------------------------------- parameters
class DistillParams(BaseModel):
    """Online distillation ([P] PULSE paper, [CODE] official PULSE code, [CPU] 2-core default)."""

    model_config = ConfigDict(extra="forbid")

    num_envs: EnvCount = Field(64, description="parallel envs ([CODE]/[P] Table 4 'batch size' 3072; [CPU] 64)")
    horizon: int = Field(32, ge=1, description="steps per env per iteration; chunk = num_envs × horizon ([CODE] 32)")
    total_env_steps: int = Field(2_000_000, ge=1, description="budget in env steps, rounded up to whole iterations ([P] ~1e9)")
    epochs: int = Field(2, ge=1, description="passes over each chunk")
    minibatch_envs: int = Field(
        16, ge=1, description="env columns per minibatch; each keeps its horizon steps in time order (minibatch = this × horizon samples)"
    )
    lr: LearningRate = Field(5e-4, description="Adam learning rate ([P] 5e-4)")
    lr_end: LearningRate | None = Field(
        None,
        description="decay the learning rate linearly from lr at progress 0 to lr_end at progress 1 (ours: a student "
        "whose clips swing between evaluations at a constant rate may settle at a lower one); None: lr throughout "
        "([P] Table 4 and [CODE] keep 5e-4 constant)",
    )
    init_latent: Path | None = Field(
        None,
        description="start the student from this latent file's weights (a latent.pt or a distill.pt; relative to the spec "
        "file; same architecture) instead of fresh ones, e.g. to continue a distillation with another schedule (ours). "
        "Used only when the stage has no distill.pt yet; progress, the budget and the β anneal count this stage's steps",
    )
    label: Literal["policy_output", "pd_targets"] = Field(
        "policy_output",
        description="what the student learns: the teacher's raw policy output ([P]/[CODE]: PHC's normalized absolute "
        "action) or its PD targets in rad. Use 'pd_targets' with a teacher whose output needs the reference to become "
        "PD targets (PHC `action: residual`): tasks have no reference, so a decoder must produce targets on its own",
    )
    max_grad_norm: float | None = Field(50.0, gt=0, description="global gradient-norm clip; None = off ([CODE] 50)")
    act_with: Literal["student", "teacher", "mixture"] = Field(
        "student",
        description="who drives the simulator: 'student' ([P] PULSE/DAgger: the student acts, the teacher labels), "
        "'teacher' (behaviour cloning) or 'mixture' (DAgger's β: the teacher with probability β per env and step)",
    )
    mixture_beta: tuple[float, float] = Field((1.0, 0.0), description="'mixture': β at progress 0 and from mixture_anneal_end on (linear in between)")
    mixture_anneal_end: float = Field(0.5, gt=0, le=1, description="'mixture': progress at which β reaches mixture_beta[1]")
    sample_latent: bool = Field(True, description="rollouts sample z from the encoder ([P]/[CODE]); false: z = encoder mean")
    termination_threshold: float = Field(
        0.5, gt=0, description="terminate when the mean body-position error exceeds this, m ([P] success criterion 0.5; PHC+ training [CODE] 0.25 on any body)"
    )
    termination_grace: int = Field(0, ge=0, description="steps after a reset that are never checked for termination")
    fail_states: FailStateParams | None = Field(
        None,
        description="fallen-state starts and bonus recovery episodes during distillation (mocap.fail_states), so the "
        "student (and PULSE's prior) sees get-up states: [CODE] PULSE distills with fallInitProb 0.1 and "
        "recoveryEpisodeProb 0.3 (fall_init_prob, recovery_episode_prob); [P] does not mention them; None: off",
    )
    getup_starts: GetUpStartParams | None = Field(
        None,
        description="a fallen start (fail_states.fall_init_prob) is given the get-up clip that lies like the humanoid, laid onto it, "
        "then its last frame held at rest (mocap.getup_starts), for a teacher trained with the phc imitator's getup_starts; "
        "[I], not in PULSE. None: the RSI clip's reference",
    )
    episode_steps: int = Field(300, ge=1, description="time limit in control steps ([CODE] 300 = 10 s at 30 Hz)")
    control_grid: bool = Field(
        True,
        description="start times on the control-rate grid and the reference read from a table precomputed at those times "
        "(MotionLibrary.use_control_grid, as the phc env); False: continuous start times, interpolated every step",
    )
    hard_negative: bool = Field(True, description="clip sampling weights follow per-clip failure counts (PHC+ soft mining)")
    hard_negative_floor: float = Field(0.2, ge=0, le=1, description="share of sampling mass kept on the base weights ([CODE] 0)")
    hard_negative_decay: float = Field(1.0, gt=0, le=1, description="failure counts are multiplied by this before each addition ([CODE] 1)")
    update_every: int = Field(256, ge=1, description="finished training episodes between failure-rate updates of the counts")
    eval_every: int = Field(
        50, ge=0, description="iterations between evaluations of the student as an imitator (also at the end); 0 disables ([CODE] 500 epochs)"
    )
    eval_num_envs: int = Field(64, ge=1, description="clips evaluated in parallel")
    eval_horizon: float | None = Field(None, gt=0, description="seconds per evaluation episode of looping clips; None: episode_steps × dt")
    torch_threads: ThreadCount | None = Field(1, description="torch intra-op threads for this stage (None: keep the process setting)")
    max_consecutive_faults: int = Field(10, ge=0, description="stop after this many consecutive batches with non-finite values (each is skipped); 0: only skip")
    checkpoint_every: int = Field(10, ge=1, description="iterations between checkpoints (also at the end and on Ctrl-C)")
    print_every: int = Field(10, ge=1, description="iterations between progress lines when the console is not a terminal")

    @model_validator(mode="after")
    def _check(self) -> "DistillParams":
        check_getup_starts(self.getup_starts, self.fail_states)
        if self.minibatch_envs > self.num_envs:
            raise ValueError(f"minibatch_envs {self.minibatch_envs} exceeds num_envs {self.num_envs}")
        for b in self.mixture_beta:
            if not 0.0 <= b <= 1.0:
                raise ValueError(f"mixture_beta values are probabilities in [0, 1], got {self.mixture_beta}")
        return self

    @property
    def batch_size(self) -> int:
        return self.num_envs * self.horizon

    @property
    def iterations(self) -> int:
        return math.ceil(self.total_env_steps / self.batch_size)


# ---------------------------------------------------------------------------------- pure helpers
def distill_lr(progress: float, lr: float, lr_end: float | None) -> float:
    """The learning rate at ``progress`` in [0, 1]: ``lr`` when ``lr_end`` is None, else linear from
    ``lr`` at 0 to ``lr_end`` at 1 (clamped outside)."""
    if lr_end is None:
        return float(lr)
    t = min(max(float(progress), 0.0), 1.0)
    return float(lr + (lr_end - lr) * t)


def mixture_beta(progress: float, start: float, end: float, anneal_end: float) -> float:
    """DAgger's β (probability that the teacher acts): ``start`` at progress 0, linear to ``end`` at
    ``anneal_end``, ``end`` afterwards."""
    if progress >= anneal_end:
        return float(end)
    return float(start + (end - start) * max(progress, 0.0) / anneal_end)


__all__ = ["DistillParams", "distill_lr", "mixture_beta"]
