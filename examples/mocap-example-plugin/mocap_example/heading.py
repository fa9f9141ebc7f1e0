"""The example plugin's ``face_heading`` task: turn to face a target heading.

goal (N, 2): the target direction (cos, sin) in each humanoid's heading frame;
reward (N,): cos(target heading - current heading), at most 1;
terminated (N,): the root is below ``fall_height`` (a fall).
"""

from __future__ import annotations

import math
from typing import Any

import torch
from torch import Tensor

from mocap.interfaces import Task
from mocap.rotations import heading_angle
from mocap.skeleton import Skeleton
from mocap.state import SimState

from mocap_example import FaceHeadingParams


def wrap(a: Tensor) -> Tensor:
    return torch.atan2(torch.sin(a), torch.cos(a))


class FaceHeading(Task):
    goal_dim = 2
    max_reward = 1.0

    def __init__(self, params: FaceHeadingParams, *, skeleton: Skeleton, num_envs: int, device: Any = "cpu", seed: int | None = None):
        self.p = params
        self.skeleton = skeleton
        self.num_envs = int(num_envs)
        self.device = torch.device(device)
        self.episode_steps = int(params.episode_steps)
        self.gen = torch.Generator().manual_seed(int(params.seed if seed is None else seed))
        self.target = torch.zeros(self.num_envs, device=self.device)
        self.since_change = torch.zeros(self.num_envs, dtype=torch.long, device=self.device)
        self._err_sum = 0.0
        self._facing = 0.0
        self._n = 0
        self._falls = 0
        self._episodes = 0

    # -------------------------------------------------------------------------- goals
    def _sample(self, env_ids: Tensor, yaw: Tensor) -> None:
        k = int(env_ids.numel())
        if k == 0:
            return
        u = torch.rand(k, generator=self.gen) * 2.0 - 1.0
        offset = u * math.radians(self.p.max_turn_deg)
        self.target[env_ids] = wrap(yaw.to(self.device) + offset.to(self.device))
        self.since_change[env_ids] = 0

    def reset(self, env_ids: Tensor, state: SimState) -> None:
        env_ids = env_ids.to(self.device).long()
        yaw = heading_angle(state.root_rot).to(self.device)[env_ids]  # ``state`` holds all N envs
        self._sample(env_ids, yaw)
        self._episodes += int(env_ids.numel())

    def step(self, state: SimState) -> None:
        self.since_change += 1
        due = torch.nonzero(self.since_change >= self.p.change_steps).flatten()
        if due.numel():
            self._sample(due, heading_angle(state.root_rot)[due.to(state.root_rot.device)])

    # ---------------------------------------------------------------------- role calls
    def _error(self, state: SimState) -> Tensor:
        return wrap(self.target - heading_angle(state.root_rot).to(self.device))

    def observe(self, state: SimState) -> Tensor:
        e = self._error(state)
        return torch.stack((torch.cos(e), torch.sin(e)), -1)

    def reward(self, state: SimState, actions: Tensor) -> Tensor:
        e = self._error(state)
        self._err_sum += float(e.abs().sum())
        self._facing += float((e.abs() < math.radians(15.0)).sum())
        self._n += int(e.numel())
        return torch.cos(e)

    def terminated(self, state: SimState) -> Tensor:
        fallen = (state.root_pos[:, 2] < self.p.fall_height).to(self.device)
        self._falls += int(fallen.sum())
        return fallen

    def metrics(self) -> dict[str, float]:
        out: dict[str, float] = {}
        if self._n:
            out["heading_error_deg"] = math.degrees(self._err_sum / self._n)
            out["facing_rate"] = self._facing / self._n
        if self._episodes:
            out["fall_rate"] = self._falls / self._episodes
        self._err_sum = self._facing = 0.0
        self._n = self._falls = self._episodes = 0
        return out

    # --------------------------------------------------------------------------- resume
    def state_dict(self) -> dict[str, Any]:
        return {"target": self.target.clone(), "since_change": self.since_change.clone(), "rng": self.gen.get_state()}

    def load_state_dict(self, state: dict[str, Any]) -> None:
        self.target.copy_(state["target"].to(self.device))
        self.since_change.copy_(state["since_change"].to(self.device))
        self.gen.set_state(state["rng"])


def make_face_heading(params: FaceHeadingParams, *, skeleton: Skeleton, num_envs: int, device: Any = "cpu", seed: int | None = None, **_: Any) -> FaceHeading:
    return FaceHeading(params, skeleton=skeleton, num_envs=num_envs, device=device, seed=seed)
