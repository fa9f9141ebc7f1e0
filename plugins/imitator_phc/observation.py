"""PHC's policy observation and action code, shared by :class:`~mocap_phc.env.ImitationEnv` and the
trained imitator: :class:`PHCObservation` (the flat ``[s^p | s^g]`` input) and :class:`PolicyImitator`
(an imitator from a policy on that observation, actions mapped by :class:`~mocap.pd_actions.ActionMap`)."""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any, Literal

import torch
from torch import Tensor

from mocap.interfaces import Imitator
from mocap.observations import SixD, imitation_goal_dim, proprioception_and_goal, proprioception_dim
from mocap.pd_actions import ActionMap
from mocap.state import HumanoidState, MotionFrames, Observations, SimState


# ------------------------------------------------------------------------------- observations
@dataclass(frozen=True)
class PHCObservation:
    """PHC's policy input: proprioception s^p and the imitation goal s^g (:mod:`mocap.observations`).

    The flat policy observation is ``[s^p | s^g]``; ``extra["ref_dof_pos"]`` carries the next
    reference's DoF angles for the residual action mapping (not part of the flat vector).
    """

    goal: Literal["rot", "keypoint"] = "rot"
    sixd: Literal["zhou", "tan_norm"] = "zhou"
    recovery: Any = None  # RecoveryGoalParams: far from the reference, imitate its root only (mocap_phc.recovery)
    frames: int = 1  # reference frames in the goal: t + 1 and frames - 1 later ones (ref_next.ahead)

    def dim(self, num_bodies: int) -> int:
        return proprioception_dim(num_bodies) + self.frames * imitation_goal_dim(num_bodies, self.goal)

    def __call__(self, state: HumanoidState, ref_next: HumanoidState) -> Observations:
        extra: dict[str, Any] = {}
        later: tuple[HumanoidState, ...] = ()
        if self.frames > 1:
            later = ref_next.ahead[: self.frames - 1] if isinstance(ref_next, MotionFrames) else ()
            if len(later) != self.frames - 1:
                raise ValueError(
                    f"this imitator observes {self.frames} reference frames but got {1 + len(later)}: "
                    "build the reference with MotionLibrary.frames_ahead(..., steps=imitator.reference_steps)"
                )
        if self.recovery is not None:
            from mocap_phc.recovery import recovery_reference

            ref_next, far = recovery_reference(state, ref_next, self.recovery)
            later = tuple(recovery_reference(state, r, self.recovery)[0] for r in later)
            extra["recovering"] = far
        proprio, goal = proprioception_and_goal(state, ref_next, self.goal, self.sixd, later)
        # no per-step nan_to_num: simulators put an unstable env back to a finite state
        # (SimState.unstable), so the inputs here are finite
        return Observations(proprio=proprio.float(), goal=goal.float(), extra={"ref_dof_pos": ref_next.dof_pos, **extra})

    @staticmethod
    def flatten(obs: Observations) -> Tensor:
        """(N, P + G) policy input."""
        assert obs.goal is not None
        return torch.cat((obs.proprio, obs.goal), dim=-1)


# ------------------------------------------------------------------------------------ actions
class PolicyImitator(Imitator):
    """An :class:`Imitator` from a policy on PHC's flat observation: ``observe`` builds
    :class:`PHCObservation`, ``act`` runs the policy and maps its action with :class:`ActionMap`.

    ``policy``: an object with ``mean_action(obs)`` and ``act(obs) -> (action, ...)`` (a
    :class:`mocap.rl.networks.ActorCritic`), or a plain callable ``obs -> action`` (deterministic).
    """

    def __init__(self, observation: PHCObservation, action_map: ActionMap, policy: Any = None, device: torch.device | str = "cpu"):
        self.observation = observation
        self.reference_steps = observation.frames
        self.action_map = action_map
        self.policy = policy
        self.device = torch.device(device)

    def observe(self, state: SimState, reference: MotionFrames) -> Observations:
        return self.observation(state, reference)

    @property
    def proprio_sixd(self) -> SixD:
        return self.observation.sixd

    def policy_action(self, flat_obs: Tensor, deterministic: bool = True) -> Tensor:
        if self.policy is None:
            raise RuntimeError("this imitator has no trained policy (build it with a checkpoint)")
        x = flat_obs.to(self.device)
        with torch.no_grad():
            if hasattr(self.policy, "mean_action"):
                if deterministic:
                    return self.policy.mean_action(x)
                out = self.policy.act(x)
                return out[0] if isinstance(out, tuple) else out
            return self.policy(x)

    def policy_output(self, obs: Observations, deterministic: bool = True) -> Tensor:
        """The policy's raw action (normalized absolute targets or a residual), before :class:`ActionMap`."""
        return self.policy_action(PHCObservation.flatten(obs), deterministic).to(obs.proprio.device)

    def to_pd_targets(self, obs: Observations, output: Tensor) -> Tensor:
        return self.action_map(output, obs.extra.get("ref_dof_pos"))

    def act(self, obs: Observations, deterministic: bool = True) -> Tensor:
        return self.to_pd_targets(obs, self.policy_output(obs, deterministic))
