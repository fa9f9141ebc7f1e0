"""Tiny distillation runs (:mod:`mocap.distill`) of PULSE's Table 3 / App. C.3 latent variants, moved
from ``test_pulse_ablations.py``: each lowers the action loss, and the RL term refuses a
teacher-driven rollout."""

from __future__ import annotations

import io
import json
import types
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import pytest
import torch
from rich.console import Console

torch.set_num_threads(1)

from mocap.distill import DistillParams
from mocap.distill_trainer import DistillError, DistillTrainer
from mocap.interfaces import Box, StageResult
from mocap.runlog import MetricsLogger
from mocap_pulse.latent import PulseLatent, PulseParams, make_pulse


# ------------------------------------------------------------------------- tiny distillations
STUDENT = {
    "latent_dim": 16,
    "encoder_hidden": [64],
    "prior_hidden": [32],
    "decoder_hidden": [64, 64],
    "rl_critic_hidden": [32],
}
RUN_VARIANTS = {
    "sphere": {"latent_kind": "sphere"},
    "vq": {"latent_kind": "vq", "vq_partitions": 4, "vq_codebook_size": 16},
    "rl_term": {"rl_term": True, "rl_weight": 0.01},
    "standard_prior_no_regu": {"prior": "standard", "regu": False},
}


@pytest.fixture(scope="module")
def walk(amp):
    from mocap.motion.deepmimic import DeepMimicParams, DeepMimicSource

    return DeepMimicSource(DeepMimicParams(clips=["walk"])).load(amp)


@pytest.fixture(scope="module")
def teacher_file(amp, walk, tmp_path_factory):
    """A small random PHC policy (residual actions), its normalizer fitted to the walk's states."""
    from mocap.motion.library import MotionLibrary
    from mocap.rl.networks import ActorCritic, save_policy
    from mocap_phc.env import PHCObservation

    torch.manual_seed(0)
    obs_dim = 15 * amp.num_bodies - 2 + 24 * amp.num_bodies
    model = ActorCritic(obs_dim, Box((amp.num_dofs,)), actor_hidden=(32,), critic_hidden=(8,))
    lib = MotionLibrary(walk, amp)
    ids, times = lib.sample(64, generator=torch.Generator().manual_seed(0))
    model.obs_norm.update(PHCObservation.flatten(PHCObservation()(lib.frames(ids, times), lib.frames(ids, times + 1 / 30))))
    with torch.no_grad():
        model.action_head.weight.mul_(5.0)
    path = tmp_path_factory.mktemp("teacher") / "policy.pt"
    save_policy(path, model)
    torch.optim.Adam([torch.zeros(1, requires_grad=True)])  # the first optimizer of a process imports torch._dynamo (seconds)
    return path


@dataclass
class Ctx:
    """The part of :class:`mocap.pipeline.StageContext` the distill trainer uses."""

    workdir: Path
    skeleton: Any
    motions: Any
    teacher_file: Path
    student: dict[str, Any]
    seed: int = 0
    device: str = "cpu"
    console: Console = field(default_factory=lambda: Console(file=io.StringIO()))

    def __post_init__(self) -> None:
        self.log = MetricsLogger(self.workdir / "metrics.jsonl", "latent")
        self.upstream = {"imitator": StageResult(checkpoint=self.teacher_file)}

    def stage_component(self, stage: str | None = None, checkpoint: Path | None = None) -> Any:
        from mocap_phc.imitator import PHCParams, make_phc

        if stage == "imitator":
            return make_phc(
                PHCParams(action="residual"),
                skeleton=self.skeleton,
                checkpoint=checkpoint,
            )
        return make_pulse(PulseParams(**self.student), skeleton=self.skeleton, checkpoint=checkpoint)

    def build(self, path: str, **kwargs: Any) -> Any:
        from mocap_sim_mujoco.simulator import MujocoSimulator

        if path == "motions":
            return types.SimpleNamespace(load=lambda skeleton: self.motions)
        return MujocoSimulator(
            skeleton=kwargs["skeleton"],
            num_envs=kwargs["num_envs"],
            seed=0,
            dtype=torch.float32,
        )

    def should_stop(self) -> bool:
        return False

    def spec_yaml(self) -> str:
        return "name: fake\n"


def distill(ctx: Ctx, params: DistillParams) -> list[dict[str, Any]]:
    try:
        DistillTrainer(params).run(ctx)
    finally:
        ctx.log.close()
    return [json.loads(line) for line in (ctx.workdir / "metrics.jsonl").read_text().splitlines()]


@pytest.mark.parametrize("variant", sorted(RUN_VARIANTS))
def test_tiny_distillation_lowers_the_action_loss(variant, amp, walk, teacher_file, tmp_path):
    params = DistillParams(
        num_envs=4,
        horizon=16,
        total_env_steps=4 * 16 * 8,
        epochs=6,
        minibatch_envs=2,
        lr=2e-3,
        eval_every=0,
    )
    recs = distill(
        Ctx(tmp_path, amp, walk, teacher_file, {**STUDENT, **RUN_VARIANTS[variant]}),
        params,
    )
    loss = [r["loss/action"] for r in recs]
    assert len(loss) == 8
    first, last = sum(loss[:2]) / 2, sum(loss[-2:]) / 2
    assert last < 0.7 * first, (variant, loss)
    if variant == "rl_term":
        assert all({"loss/rl_policy", "loss/rl_value", "rollout/rl_reward"} <= set(r) for r in recs)
        assert all(0.0 < r["rollout/rl_reward"] <= 1.0 for r in recs)
        assert recs[-1]["loss/rl_value"] < recs[0]["loss/rl_value"]  # the critic learns
    if variant == "vq":
        assert all(r["loss/perplexity"] > 1.0 for r in recs)
    latent = make_pulse(
        PulseParams(**{**STUDENT, **RUN_VARIANTS[variant]}),
        skeleton=amp,
        checkpoint=tmp_path / "latent.pt",
    )
    assert isinstance(latent, PulseLatent)


def test_rl_term_refuses_a_teacher_driven_rollout(amp, walk, teacher_file, tmp_path):
    params = DistillParams(
        num_envs=2,
        horizon=2,
        total_env_steps=4,
        minibatch_envs=2,
        eval_every=0,
        act_with="teacher",
    )
    with pytest.raises(DistillError, match="act_with: student"):
        distill(Ctx(tmp_path, amp, walk, teacher_file, {**STUDENT, "rl_term": True}), params)
