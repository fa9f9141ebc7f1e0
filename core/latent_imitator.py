"""An :class:`~mocap.interfaces.Imitator` made of a latent space and the imitator it was distilled from.

PULSE (Table 1) and the other distilled latent spaces are evaluated *as imitators*: the teacher's
observation (proprioception + next-frame imitation goal), ``z`` = the encoder's mean, the decoder's
action, and the teacher's mapping from raw policy output to PD targets. :class:`LatentImitator`
packages exactly that, so :func:`mocap.imitation_eval.evaluate_imitator`, ``rollout_imitation`` and
``mocap eval`` treat a latent space like any imitator.

Two kinds of latent space are handled:

* a :class:`~mocap.interfaces.DistillableLatent` (it has ``student_action``): its output is in the
  teacher's raw policy-output space, mapped by ``imitator.to_pd_targets``;
* any other :class:`~mocap.interfaces.LatentSpace`: ``decoder(obs, encoder(obs).mean)`` already
  gives PD targets.

A latent space that can map its decoder output to PD targets once it knows the teacher
(``attach_imitator(imitator)``, e.g. PULSE) is attached on construction.
"""

from __future__ import annotations

from typing import Any, cast

import torch
from torch import Tensor

from mocap.interfaces import DistillableLatent, Imitator, LatentSpace
from mocap.state import MotionFrames, Observations, SimState


def observations_to(obs: Observations, device: torch.device | str) -> Observations:
    """A copy of ``obs`` with every tensor on ``device``."""
    return Observations(
        proprio=obs.proprio.to(device),
        goal=None if obs.goal is None else obs.goal.to(device),
        extra={k: v.to(device) if isinstance(v, Tensor) else v for k, v in obs.extra.items()},
    )


class LatentImitator(Imitator):
    """Imitate with ``latent`` (module docstring); ``imitator`` supplies ``observe`` and ``to_pd_targets``.

    Args:
        imitator: the teacher (the imitator the latent space was distilled from, or one with the
            same observation and action mapping).
        latent: the trained latent space.
        device: where the latent's networks run (default: where its parameters are).

    ``act(obs, deterministic=True)`` uses ``z`` = the encoder mean (the paper's evaluation);
    ``deterministic=False`` samples ``z`` from the encoder.
    """

    def __init__(self, imitator: Imitator, latent: LatentSpace, device: torch.device | str | None = None):
        if not latent.has_encoder:
            raise ValueError(f"{type(latent).__name__} has no encoder (has_encoder False): there is no imitation through it to evaluate")
        if imitator.reference_steps != 1:
            raise ValueError(f"the imitator observes {imitator.reference_steps} reference frames; a latent space's encoder reads one")
        self.imitator = imitator
        self.latent = latent
        if device is None:
            first = next(iter(latent.parameters()), None)
            device = first.device if first is not None else "cpu"
        self.device = torch.device(device)
        self.distillable = isinstance(latent, DistillableLatent)
        latent.attach_imitator(imitator)

    def observe(self, state: SimState, reference: MotionFrames) -> Observations:
        return self.imitator.observe(state, reference)

    def policy_output(self, obs: Observations, deterministic: bool = True) -> Tensor:
        """The latent's action: the student's raw output (distillable latents) or PD targets (others)."""
        x = observations_to(obs, self.device)
        with torch.no_grad():
            if self.distillable:
                # checked once in __init__ (self.distillable); a Protocol isinstance per step is not free
                out = cast(DistillableLatent, self.latent).student_action(x, sample=not deterministic)
            else:
                enc = self.latent.encoder(x)
                z = enc.mean if deterministic or enc.std is None else enc.mean + enc.std * torch.randn_like(enc.mean)
                out = self.latent.decoder(x, z)
        return out.to(obs.proprio.device)

    def to_pd_targets(self, obs: Observations, output: Tensor) -> Tensor:
        return self.imitator.to_pd_targets(obs, output) if self.distillable else output

    def act(self, obs: Observations, deterministic: bool = True) -> Tensor:
        return self.to_pd_targets(obs, self.policy_output(obs, deterministic))


class PDTargetTeacher(Imitator):
    """A teacher whose "policy output" is its PD targets (and whose mapping is the identity).

    With it, a student learns PD targets directly, so its decoder drives the simulator without the
    reference motion (the ``label: pd_targets`` switch of :class:`DistillParams`).
    """

    def __init__(self, imitator: Imitator):
        self.imitator = imitator
        self.reference_steps = imitator.reference_steps

    @property
    def policy(self) -> Any:  # type: ignore[override]
        """The wrapped imitator's policy network (students may copy its input statistics)."""
        return self.imitator.policy

    def observe(self, state: Any, reference: Any) -> Any:
        return self.imitator.observe(state, reference)

    def act(self, obs: Any, deterministic: bool = True) -> Tensor:
        return self.imitator.act(obs, deterministic)

    def policy_output(self, obs: Any, deterministic: bool = True) -> Tensor:
        return self.imitator.act(obs, deterministic)

    def to_pd_targets(self, obs: Any, output: Tensor) -> Tensor:
        return output


def latent_imitator(imitator: Imitator, latent: LatentSpace, device: torch.device | str | None = None) -> LatentImitator:
    """Convenience: ``LatentImitator(imitator, latent, device)`` with the latent in eval mode."""
    latent.eval()
    return LatentImitator(imitator, latent, device)


__all__ = ["LatentImitator", "PDTargetTeacher", "latent_imitator", "observations_to"]
