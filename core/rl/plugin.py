"""Registers the RL trainers (entry point ``rl = "mocap.rl.plugin"`` in the ``mocap`` group)."""

from __future__ import annotations

from mocap.hooks import hookimpl
from mocap.metric_display import MetricInfo
from mocap.plugins import lazy
from mocap.rl.ppo_params import PPOParams


#: the episode statistics PPO logs under ``episode/`` (the env's episode dict; tasks add their own)
EPISODE_METRICS = {
    "return": MetricInfo("return"),
    "length": MetricInfo("episode length", "steps"),
    "normalized_return": MetricInfo("normalized return"),
    "success": MetricInfo("success rate"),
}


@hookimpl
def register_trainers(register):
    register(
        "ppo",
        lazy("mocap.rl.ppo:PPOTrainer"),
        params=PPOParams,
        description="PPO with GAE on the stage's VecEnv (make_env); checkpoints and resumes in the stage dir, writes policy.pt",
        metrics=EPISODE_METRICS,
    )
