"""Registers the RL trainers (entry point ``rl = "mocap.rl.plugin"`` in the ``mocap`` group)."""

from __future__ import annotations

from mocap.hooks import hookimpl
from mocap.rl.ppo import PPOParams, PPOTrainer


@hookimpl
def register_trainers(register):
    register(
        "ppo",
        PPOTrainer,
        params=PPOParams,
        description="PPO with GAE on the stage's VecEnv (make_env); checkpoints and resumes in the stage dir, writes policy.pt",
    )
