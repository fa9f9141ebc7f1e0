"""The params of the VMP components, torch-free so that validating a spec (``mocap validate``) and
listing the plugins import no torch: the latent space ``vmp`` (:class:`VmpParams`, re-exported by
:mod:`mocap_vmp.latent`), the trainers ``supervised`` (:class:`SupervisedParams`, re-exported by
:mod:`mocap_vmp.trainer`) and ``vmp_track`` (:class:`VmpTrackParams`, re-exported by
:mod:`mocap_vmp.track_trainer`). The tracker's params: :mod:`mocap_vmp.tracking_params`.
"""

from __future__ import annotations

from typing import Literal

from pydantic import BaseModel, ConfigDict, Field, model_validator

from mocap.rl.ppo_params import PPOParams
from mocap_vmp.tracking_params import VmpTrackerParams


class VmpParams(BaseModel):
    """VMP stage I (the motion VAE and its features). Tags: [P] paper, [X] our choice (not in the paper)."""

    model_config = ConfigDict(extra="forbid")

    window_half: int = Field(
        30,
        ge=1,
        description="W: windows hold 2W+1 frames [P: W = 30, 61 frames, 1 s at the paper's rate]; frames are the "
        "clips' own frames (no resampling [X]: clips at different rates give windows of different durations)",
    )
    latent_dim: int = Field(64, ge=1, description="d_z [P: 64]")
    channels: int = Field(48, ge=1, description="conv width [X: the paper gives no widths; 96 reaches its ~0.8 M parameters; 48 is the CPU default]")
    res_blocks: int = Field(4, ge=0, description="ResNet blocks in encoder and decoder [P: 4]")
    downsample: int = Field(2, ge=0, description="stride-2 conv layers before the ResNet blocks [X: not in the paper]")
    dilation_growth: int = Field(3, ge=1, description="ResBlock i has dilation growth^i [X: Jukebox-style; not in the paper]")
    end_effectors: list[str] | None = Field(
        None,
        description="bodies whose root-relative positions form p [P: hands and feet]; None = the hands and feet among "
        "the skeleton's end effectors (names containing 'hand' or 'foot')",
    )
    std_min: float = Field(1e-6, gt=0, description="floor of the standardization std, for features that never vary in the data [X: not in the paper]")
    latent_for_policy: Literal["mean", "sample"] = Field(
        "mean", description="z_t given to the policy and precomputed per frame: posterior mean or a sample [X: paper silent]"
    )
    task_action: Literal["latent", "residual"] = Field(
        "latent",
        description="a task policy's action (beyond the paper: VMP only tracks): 'latent' = z itself (prior N(0, I)); "
        "'residual' = z = the encoding of the current frame held over the window + a (mocap_vmp.task) [X]",
    )
    task_action_clip: float | None = Field(
        None, gt=0, description="bound of the task action space Box(d_z): actions clamped to [-clip, clip]; None = unbounded [X]"
    )


class SupervisedParams(BaseModel):
    """VAE training (paper section 3.5-3.6). Tags: [P] paper, [T1] the paper's garbled Table 1, [X] ours."""

    model_config = ConfigDict(extra="forbid")

    num_iterations: int = Field(50_000, ge=1, description="optimizer steps [T1: 50,000 'epochs', read as iterations]")
    batch_size: int = Field(512, ge=1, description="windows per step [P: 512]")
    lr: float = Field(3e-3, gt=0, description="RAdam initial learning rate [P: 0.003]")
    sgdr_t0: int = Field(1000, ge=1, description="SGDR first cycle length, steps [T1: 1000]")
    sgdr_t_mult: int = Field(5, ge=1, description="SGDR cycle growth factor [T1: 5]")
    sgdr_eta_min: float = Field(0.0, ge=0, description="SGDR minimum learning rate [X: not given; torch's default 0]")
    beta: float = Field(0.002, ge=0, description="KL weight beta [P: 0.002]")
    kl_cycles: int = Field(7, ge=1, description="cyclical KL annealing cycles over the run [T1: 7]")
    kl_ramp_ratio: float = Field(0.5, ge=0, le=1, description="fraction of each cycle over which beta ramps from 0 [T1: 0.5]")
    max_grad_norm: float | None = Field(None, gt=0, description="gradient-norm clip; None = off [X: the paper names none]")
    torch_threads: int | None = Field(1, ge=1, description="torch intra-op threads for this stage (None: keep the process setting)")
    checkpoint_every: int = Field(500, ge=1, description="steps between checkpoints (also at the end and on Ctrl-C)")
    print_every: int = Field(100, ge=1, description="steps between progress lines")
    latent_batch: int = Field(1024, ge=1, description="windows per batch when precomputing the per-frame latents")


class TrackerDistillParams(BaseModel):
    """Warm start of the tracking policy by online distillation (DAgger) from the spec's trained
    imitator, before PPO [X: not in VMP, whose tracker is trained by RL alone; :mod:`mocap_vmp.tracker_distill`]."""

    model_config = ConfigDict(extra="forbid")

    total_env_steps: int = Field(5_000_000, ge=1, description="distillation budget in env steps (rounded up to whole iterations)")
    num_envs: int = Field(128, ge=1, description="parallel envs")
    horizon: int = Field(32, ge=1, description="steps per env per iteration")
    epochs: int = Field(2, ge=1, description="passes over each iteration's samples")
    minibatch_size: int = Field(1024, ge=1, description="samples per gradient step")
    lr: float = Field(5e-4, gt=0, description="Adam learning rate (PULSE's distillation: 5e-4)")
    lr_end: float = Field(5e-5, gt=0, description="the learning rate decays linearly to this at the end of the budget")
    beta: tuple[float, float] = Field(
        (0.5, 0.0),
        description="DAgger's beta_i: each env step is driven by the teacher's action with this probability, else by the "
        "student's mean action; annealed linearly from the first value to the second over the budget",
    )
    value_coef: float = Field(
        0.5,
        ge=0,
        description="weight of a critic fit to TD(lambda) returns of the tracking reward on the same samples (gamma and "
        "lambda of the ppo params), so that PPO starts with a critic that knows the distilled policy; 0 = off",
    )
    max_grad_norm: float = Field(1.0, gt=0, description="global gradient-norm clip")
    torch_threads: int | None = Field(1, ge=1, description="torch intra-op threads (None: keep the process setting)")
    checkpoint_every: int = Field(20, ge=1, description="iterations between resumable checkpoints (also at the end and on Ctrl-C)")
    print_every: int = Field(10, ge=1, description="iterations between progress lines when the console is not a terminal")

    @model_validator(mode="after")
    def _valid(self) -> "TrackerDistillParams":
        if not all(0.0 <= b <= 1.0 for b in self.beta):
            raise ValueError(f"beta values must lie in [0, 1], got {self.beta}")
        if self.minibatch_size > self.num_envs * self.horizon:
            raise ValueError(f"minibatch_size {self.minibatch_size} exceeds num_envs x horizon = {self.num_envs * self.horizon}")
        return self


class VmpTrackParams(BaseModel):
    """Both VMP stages: the VAE's training (``vae``), PPO (``ppo``) and the tracking env (``tracker``)."""

    model_config = ConfigDict(extra="forbid")

    vae: SupervisedParams = Field(
        default_factory=SupervisedParams,
        description="stage I: the supervised trainer's params",
    )
    ppo: PPOParams = Field(
        default_factory=PPOParams,
        description="stage II: PPO [P: 3x512 ELU actor and critic, gamma 0.99, lambda 0.95, 5 epochs, clip 0.2, max grad norm 1.0; "
        "the defaults here are the project's CPU recipe]",
    )
    tracker: VmpTrackerParams = Field(
        default_factory=VmpTrackerParams,
        description="stage II: conditioning, reward, termination, episodes",
    )
    distill: TrackerDistillParams | None = Field(
        None,
        description="stage II warm start: distil the spec's imitator into the tracking policy before PPO [X]; "
        "None = PPO from random weights (the paper's procedure)",
    )


__all__ = ["SupervisedParams", "TrackerDistillParams", "VmpParams", "VmpTrackParams"]
