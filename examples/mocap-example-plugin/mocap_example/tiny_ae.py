"""The example plugin's ``tiny_ae`` latent space: a tiny deterministic autoencoder.

encoder: MLP (proprio, imitation goal) -> z (deterministic, ``std`` None);
decoder: MLP (proprio, z) -> the teacher's raw policy output (mapped to PD targets by the attached
imitator, like PULSE); prior: N(0, I); task action space: z itself (a Box).
Trained by mocap's shared ``distill`` trainer (implements ``DistillableLatent``).
"""

from __future__ import annotations

from pathlib import Path
from typing import Any

import torch
from torch import Tensor, nn

from mocap.errors import UserError
from mocap.interfaces import Box, Imitator, LatentSample, LatentSpace
from mocap.observations import imitation_goal_dim, proprioception_dim
from mocap.skeleton import Skeleton
from mocap.state import Observations

from mocap_example import TinyAEParams

FORMAT = "mocap_example.tiny_ae/1"


def mlp(sizes: list[int]) -> nn.Sequential:
    layers: list[nn.Module] = []
    for i, (a, b) in enumerate(zip(sizes[:-1], sizes[1:])):
        layers.append(nn.Linear(a, b))
        if i < len(sizes) - 2:
            layers.append(nn.SiLU())
    return nn.Sequential(*layers)


class RunningNorm(nn.Module):
    def __init__(self, dim: int):
        super().__init__()
        self.register_buffer("mean", torch.zeros(dim))
        self.register_buffer("var", torch.ones(dim))
        self.register_buffer("count", torch.zeros(()))

    @torch.no_grad()
    def update(self, x: Tensor) -> None:
        x = x.reshape(-1, x.shape[-1]).float()
        n = x.shape[0]
        if n == 0:
            return
        m, v = x.mean(0), x.var(0, unbiased=False)
        tot = self.count + n
        delta = m - self.mean
        self.mean += delta * n / tot
        self.var = (self.var * self.count + v * n + delta**2 * self.count * n / tot) / tot
        self.count.fill_(float(tot))

    def forward(self, x: Tensor) -> Tensor:
        return ((x - self.mean) / torch.sqrt(self.var + 1e-5)).clamp(-5.0, 5.0)


class TinyAE(LatentSpace):
    samples_prior = True

    def __init__(self, params: TinyAEParams, *, skeleton: Skeleton):
        super().__init__()
        self.p = params
        self.latent_dim = int(params.latent_dim)
        self.proprio_dim = proprioception_dim(skeleton.num_bodies)
        self.goal_dim = imitation_goal_dim(skeleton.num_bodies, params.goal_obs)
        self.action_dim = int(skeleton.num_dofs)
        self.proprio_norm = RunningNorm(self.proprio_dim)
        self.goal_norm = RunningNorm(self.goal_dim)
        self.enc = mlp([self.proprio_dim + self.goal_dim, *params.hidden, self.latent_dim])
        self.dec = mlp([self.proprio_dim + self.latent_dim, *params.hidden, self.action_dim])
        self._imitator: list[Imitator] = []  # kept out of the module tree (not saved with the weights)

    # ----------------------------------------------------------------------- the role
    @property
    def config(self) -> dict[str, Any]:
        return {
            "format": FORMAT,
            "proprio_dim": self.proprio_dim,
            "goal_dim": self.goal_dim,
            "action_dim": self.action_dim,
            "latent_dim": self.latent_dim,
            "hidden": list(self.p.hidden),
            "goal_obs": self.p.goal_obs,
        }

    def encoder(self, obs: Observations) -> LatentSample:
        if obs.goal is None:
            raise ValueError("tiny_ae: the encoder needs the imitation goal (obs.goal)")
        x = torch.cat((self.proprio_norm(obs.proprio), self.goal_norm(obs.goal)), -1)
        z = self.enc(x)
        return LatentSample(mean=z, std=None, z=z)

    def prior(self, obs: Observations) -> LatentSample:
        shape = (*obs.proprio.shape[:-1], self.latent_dim)
        zeros = obs.proprio.new_zeros(shape)
        return LatentSample(mean=zeros, std=torch.ones_like(zeros), z=zeros)

    def decode_action(self, obs: Observations, z: Tensor) -> Tensor:
        return self.dec(torch.cat((self.proprio_norm(obs.proprio), z), -1))

    def decoder(self, obs: Observations, z: Tensor) -> Tensor:
        raw = self.decode_action(obs, z)
        return self._imitator[0].to_pd_targets(obs, raw) if self._imitator else raw

    @property
    def task_action_space(self) -> Box:
        return Box((self.latent_dim,), -self.p.task_bound, self.p.task_bound, exploration_sigma=self.p.task_sigma)

    def to_latent(self, obs: Observations, task_action: Tensor) -> Tensor:
        return task_action.clamp(-self.p.task_bound, self.p.task_bound)

    def random_action(self, obs: Observations, noise_scale: float = 1.0, generator: torch.Generator | None = None) -> Tensor:
        shape = (obs.proprio.shape[0], self.latent_dim)
        z = torch.randn(shape, generator=generator).to(obs.proprio) * noise_scale
        return self.decode_action(obs, z)

    def attach_imitator(self, imitator: Imitator) -> "TinyAE":
        self._imitator[:] = [imitator]
        return self

    # ---------------------------------------------------------- DistillableLatent
    def student_action(self, obs: Observations, sample: bool = True) -> Tensor:
        return self.decode_action(obs, self.encoder(obs).mean)

    def distill_losses(self, obs: Observations, teacher_output: Tensor, starts: Tensor, progress: float) -> dict[str, Tensor]:
        z = self.encoder(obs).mean
        action = self.decode_action(obs, z)
        action_loss = (action - teacher_output).pow(2).mean()
        z_reg = z.pow(2).mean()
        return {"loss": action_loss + self.p.z_reg * z_reg, "action": action_loss.detach(), "z_reg": z_reg.detach()}

    def update_normalizers(self, obs: Observations) -> None:
        self.proprio_norm.update(obs.proprio)
        if obs.goal is not None:
            self.goal_norm.update(obs.goal)


def make_tiny_ae(params: TinyAEParams, *, skeleton: Skeleton, checkpoint: Path | None = None, device: Any = "cpu", **_: Any) -> TinyAE:
    latent = TinyAE(params, skeleton=skeleton)
    if checkpoint is not None:
        from mocap.distill_files import load_latent_state

        saved = load_latent_state(Path(checkpoint), map_location="cpu")
        config = saved.get("config") or {}
        for key, want in latent.config.items():
            if key in config and config[key] != want:
                raise UserError(f"{checkpoint}: tiny_ae {key}: checkpoint {config[key]!r} vs spec {want!r}")
        if config.get("format") != FORMAT:
            raise UserError(f"{checkpoint}: not a tiny_ae latent (format {config.get('format')!r}); train one with the distill trainer")
        latent.load_state_dict(saved["state_dict"])
    return latent.to(device)
