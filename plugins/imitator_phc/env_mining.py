"""Per-clip bookkeeping of :class:`~mocap_phc.env.ImitationEnv`, as its base class :class:`ClipMining`:
failure statistics and clip sampling weights (hard-negative mining) and :meth:`ClipMining.evaluate_clips`
(every clip once from frame 0 in a separate simulator). The methods use the attributes that
``ImitationEnv.__init__`` sets (``library``, ``params``, ``failures``, ``observation``, ...)."""

from __future__ import annotations

from typing import TYPE_CHECKING, Any, Callable

import torch
from torch import Tensor

from mocap.interfaces import Simulator
from mocap_phc.observation import PolicyImitator

if TYPE_CHECKING:  # pragma: no cover
    from mocap.hard_negatives import FailureTracker
    from mocap.motion.library import MotionLibrary
    from mocap.pd_actions import ActionMap
    from mocap_phc.imitator import PHCParams
    from mocap_phc.observation import PHCObservation

PolicyFn = Callable[[Tensor], Tensor]


class ClipMining:
    """The hard-negative and per-clip evaluation methods of :class:`~mocap_phc.env.ImitationEnv` (module docstring)."""

    # set by ImitationEnv.__init__ (declared here for the type checker only)
    params: PHCParams
    library: MotionLibrary
    dt: float
    observation: PHCObservation
    action_map: ActionMap
    failures: FailureTracker
    last_evaluation: dict[str, Any] | None
    _eval_factory: Callable[[int], Simulator] | None
    _eval_sims: dict[int, Simulator]

    # ------------------------------------------------------------------ hard negatives
    @property
    def clip_weights(self) -> Tensor:
        """(C,) current clip sampling probabilities."""
        return self.library.weights.detach().to("cpu", torch.float64).clone()

    def clip_stats(self) -> dict[str, dict[str, float]]:
        """Per clip: finished training ``episodes``, ``failures`` (terminations), the mining count
        ``fail_count`` and the current sampling ``weight``."""
        w = self.clip_weights
        return {
            name: {
                "episodes": float(self.episodes_per_clip[i]),
                "failures": float(self.failures_per_clip[i]),
                "fail_count": float(self.fail_counts[i]),
                "weight": float(w[i]),
            }
            for i, name in enumerate(self.library.clip_names)
        }

    def _record(self, clip_ids: Tensor, failed: Tensor) -> None:
        """Count finished training episodes (the shared :class:`~mocap.hard_negatives.FailureTracker`)."""
        self.failures.record(clip_ids, failed)

    def _add_failures(self, amount: Tensor) -> None:
        self.failures.add_failures(amount)

    # per-clip failure bookkeeping lives in the shared tracker (mocap.hard_negatives)
    @property
    def fail_counts(self) -> Tensor:
        return self.failures.fail_counts

    @property
    def episodes_per_clip(self) -> Tensor:
        return self.failures.episodes_per_clip

    @property
    def failures_per_clip(self) -> Tensor:
        return self.failures.failures_per_clip

    @property
    def base_weights(self) -> Tensor:
        return self.failures.base_weights

    def evaluate_clips(self, policy_fn: PolicyFn) -> dict[str, Any]:
        """Every clip once from frame 0 with ``policy_fn`` (flat obs -> action, deterministic) in a
        separate simulator; failed clips add 1 to their failure count and the weights are refreshed.

        Horizon: the whole clip for non-looping clips, ``episode_steps`` for looping ones.
        Returns ``success_rate``, ``failed`` (clip names), ``clips`` (name -> ``success``,
        ``tracked_steps``) and ``weights`` (name -> sampling probability after the update).
        """
        from mocap.imitation_eval import episode_frames, rollout_imitation

        if self._eval_factory is None:
            raise RuntimeError("evaluate_clips needs an eval_simulator_factory")
        lib, p = self.library, self.params
        C = lib.num_clips
        imitator = PolicyImitator(self.observation, self.action_map, policy_fn)
        chunk = max(1, min(p.eval_num_envs, C))
        failed = torch.zeros(C, dtype=torch.bool)
        tracked = torch.zeros(C, dtype=torch.long)
        horizon = episode_frames(lib, torch.arange(C, device=lib.device), self.dt, p.episode_steps * self.dt).cpu()
        for start in range(0, C, chunk):
            ids = torch.arange(start, min(start + chunk, C))
            sim = self._eval_sim(len(ids))
            out = rollout_imitation(sim, lib, imitator, ids.to(lib.device), horizon[ids], threshold=p.eval_threshold)
            tr = out.traj
            valid = tr.valid()
            err = torch.linalg.vector_norm(tr.sim - tr.ref, dim=-1).mean(-1)
            bad = ((err > p.eval_threshold) & valid).any(0) | out.unstable.cpu()
            failed[ids] = bad
            tracked[ids] = (valid.sum(0) - 1).clamp_min(0)
        self._add_failures(failed.to(torch.float64))
        names = lib.clip_names
        w = self.clip_weights
        result = {
            "success_rate": float((~failed).double().mean()),
            "failed": [names[i] for i in range(C) if failed[i]],
            "clips": {names[i]: {"success": bool(~failed[i]), "tracked_steps": int(tracked[i])} for i in range(C)},
            "weights": {names[i]: float(w[i]) for i in range(C)},
        }
        self.last_evaluation = result
        return result

    def _eval_sim(self, n: int) -> Simulator:
        if n not in self._eval_sims:
            assert self._eval_factory is not None
            self._eval_sims[n] = self._eval_factory(n)
        return self._eval_sims[n]
