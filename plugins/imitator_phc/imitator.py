"""The ``phc`` imitator: parameters (every paper-vs-code switch), the factory and the trained imitator.

Defaults follow the paper wherever PHC (ICCV 2023) states a value, and the official code where
the paper is silent; each field's description says which is which.
For small CPU runs, early learning measured on 2 cores favours ``action: residual``; the code's
reward form (``reward_form: code``) is the one PHC was actually trained with. One exception to
"paper by default": ``energy_form`` defaults to the code's |tau q-dot| (see its description).

Energy scale, measured on ``amp`` (walk and kick, RSI, residual actions, c = 5e-4, code form): about
-0.2 per step with zero actions and -2.6 per step under sigma = 0.3 exploration noise, against an
imitation reward of at most 1. A return that is mostly negative teaches the policy to end episodes
early, so short CPU runs should lower ``energy_coef`` (the code's composer value 5e-5) or set it to 0.
"""

from __future__ import annotations

from pathlib import Path
from typing import Any

import torch

from mocap.skeleton import Skeleton
from mocap_phc.env import ImitationEnv, PolicyImitator
from mocap_phc.phc_params import PHCParams


class PHCImitator(PolicyImitator):
    """PHC / PHC+ imitator: ``observe`` builds [s^p | s^g] (:class:`~mocap_phc.env.PHCObservation`)
    and ``act`` maps the trained policy's action to PD targets (:class:`~mocap_phc.env.ActionMap`),
    exactly as :class:`~mocap_phc.env.ImitationEnv` does during training.

    ``observe(state, ref)`` expects ``ref`` at the *next* control time (t + 1), as the evaluator's
    ``rollout_imitation`` passes it.
    """

    def __init__(self, params: PHCParams, skeleton: Skeleton, policy: Any = None, device: torch.device | str = "cpu"):
        super().__init__(params.observation(), params.action_map(skeleton), policy, device)
        self.params = params
        self.skeleton = skeleton
        self.obs_dim = self.observation.dim(skeleton.num_bodies)

    def make_env(self, ctx: Any, num_envs: int) -> ImitationEnv:
        """The training env: the spec's motions and simulator, seeded by the stage seed."""
        from mocap.motion.library import MotionLibrary

        skeleton = self.skeleton
        motion_set = ctx.build("motions").load(skeleton)
        for path, reason in motion_set.skipped:
            ctx.console.print(f"[yellow]skipped[/] {path}: {reason}")
        library = MotionLibrary(motion_set, skeleton)
        sim = ctx.build("simulator", skeleton=skeleton, num_envs=num_envs, seed=ctx.seed)

        def eval_sim(n: int) -> Any:
            return ctx.build("simulator", skeleton=skeleton, num_envs=n, seed=ctx.seed)

        return ImitationEnv(self.params, skeleton, library, sim, seed=ctx.seed, eval_simulator_factory=eval_sim)


def make_phc(
    params: PHCParams | None = None,
    *,
    skeleton: Skeleton,
    checkpoint: str | Path | None = None,
    device: torch.device | str = "cpu",
) -> PHCImitator:
    """Registry factory: an untrained imitator (for ``make_env``) or, with ``checkpoint`` (a policy
    file of :func:`mocap.rl.networks.save_policy`), the trained one; a PMCP checkpoint (``pmcp.pt``
    of the ``pmcp`` trainer) gives a :class:`mocap_phc.pmcp.CompositeImitator`."""
    params = params or PHCParams()
    policy = None
    if checkpoint is not None:
        from mocap.rl.networks import load_policy

        try:
            policy = load_policy(Path(checkpoint), map_location=device)
        except ValueError:
            from mocap.checkpoint import load_checkpoint
            from mocap_phc.pmcp import is_pmcp_checkpoint, make_composite_imitator

            data = load_checkpoint(Path(checkpoint), map_location=device)
            if not is_pmcp_checkpoint(data):
                raise
            return make_composite_imitator(params, skeleton, data, device)
        want = params.observation().dim(skeleton.num_bodies)
        got = getattr(policy, "obs_dim", want)
        got_actions = getattr(policy, "action_dim", skeleton.num_dofs)
        if got != want or got_actions != skeleton.num_dofs:
            from mocap.checkpoint import CheckpointError, embedded_humanoid, load_checkpoint

            trained = embedded_humanoid(load_checkpoint(Path(checkpoint)))
            if trained is not None and trained != skeleton.name:
                raise CheckpointError(
                    f"{checkpoint}: this checkpoint was trained for humanoid {trained} with {got_actions} actions "
                    f"({got} observation dims); the spec asks for {skeleton.name} with {skeleton.num_dofs} ({want})"
                )
            raise CheckpointError(
                f"{checkpoint}: the policy takes {got} observation dims and gives {got_actions} actions, but phc with "
                f"obs={params.obs!r} on {skeleton.name!r} ({skeleton.num_bodies} bodies) needs {want} and {skeleton.num_dofs}"
            )
    return PHCImitator(params, skeleton, policy, device)


__all__ = ["PHCImitator", "PHCParams", "make_phc"]
