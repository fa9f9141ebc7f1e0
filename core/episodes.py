"""The episode layer every env of the framework is built on: the imitation env (:mod:`mocap_phc.env`),
VMP's tracking env (:mod:`mocap_vmp.tracking_env`), the task env (:mod:`mocap.task_env`) and the
online-distillation rollouts (:mod:`mocap.distill_episodes`).

Written once here, used by all four:

* :class:`RewardTerms` — the reward as **named, weighted terms**, ``r = sum_k w_k r_k``, in the
  order the weights are declared. The weights come from the env's params (so from the spec); an
  unknown term name is an error naming the known ones. Every term's value ``r_k`` (unweighted) is
  logged as ``reward/<name>`` without any env writing that line, and a step whose state is
  numerically unstable (or whose reward is not finite) gets reward 0.
* :class:`TerminationTerms` — termination as named boolean terms, OR-ed, each logged as
  ``terminated/<name>`` (the fraction of envs it fired in).
* :class:`ReferenceStarts` — reference-state initialization (RSI, DeepMimic Sec. 6; PHC Sec. 3.1):
  a clip drawn with the motion library's sampling weights, a start time in it (optionally from a
  failure-driven :class:`~mocap.start_sampling.AdaptiveStartSampler`), clamped so that a
  non-looping clip keeps at least one step, and optionally moved onto the control grid.
* :class:`EpisodeBook` — per-env step counters and returns; :meth:`EpisodeBook.conclude` ends a
  step the same way everywhere: the time limit, ``final_obs`` before any reset, the statistics of
  the episodes that finished (``return``, ``length``, ``success`` = ended without terminating),
  the auto-reset of those envs and their first observation in place of ``final_obs``.

The simulator's physics state is saved and restored by :mod:`mocap.sim_snapshot` (also shared).
"""

from __future__ import annotations

from typing import Any, Callable, Mapping

import torch
from torch import Tensor

from mocap.motion.library import MotionLibrary, grid_start_times
from mocap.rl.env import StepResult


# ------------------------------------------------------------------------------------ rewards
class RewardTerms:
    """Named, weighted reward terms (module docstring).

    Args:
        weights: term name -> weight, in the order the terms are summed.
        overrides: spec-given weights replacing some of ``weights`` (unknown names are an error).
        owner: names the params field in error messages (e.g. ``"phc.reward_terms"``).
    """

    def __init__(self, weights: Mapping[str, float], overrides: Mapping[str, float] | None = None, owner: str = "reward_terms"):
        self.weights: dict[str, float] = {str(k): float(v) for k, v in weights.items()}
        if overrides:
            check_term_names(overrides, self.weights, owner)
            self.weights.update({str(k): float(v) for k, v in overrides.items()})

    @property
    def names(self) -> tuple[str, ...]:
        return tuple(self.weights)

    def __call__(self, terms: Mapping[str, Tensor], unstable: Tensor | None = None) -> tuple[Tensor, dict[str, Tensor]]:
        """``(reward (N,) float64, info)``: the weighted sum of ``terms`` (which must name exactly
        the declared terms), 0 where ``unstable`` or not finite; ``info`` has ``reward/<name>``."""
        return self.zero_invalid(self.weighted_sum(terms), unstable), self.info(terms)

    def weighted_sum(self, terms: Mapping[str, Tensor]) -> Tensor:
        """(N,) float64 ``sum_k w_k r_k`` in declaration order, before any zeroing (an env that ends
        episodes on a non-finite reward reads it, then finishes with :meth:`zero_invalid`)."""
        if set(terms) != set(self.weights):
            missing, extra = sorted(set(self.weights) - set(terms)), sorted(set(terms) - set(self.weights))
            raise ValueError(f"reward terms do not match the declared ones (missing {missing}, undeclared {extra})")
        total: Tensor | None = None
        for name, w in self.weights.items():
            v = terms[name]
            part = v if w == 1.0 else w * v
            total = part if total is None else total + part
        assert total is not None, "RewardTerms needs at least one term"
        return total.double()

    @staticmethod
    def zero_invalid(total: Tensor, unstable: Tensor | None = None) -> Tensor:
        """``total`` with 0 where it is not finite or ``unstable``."""
        bad = ~torch.isfinite(total)
        if unstable is not None:
            bad = bad | unstable.to(total.device).bool()
        return torch.where(bad, torch.zeros_like(total), total)

    @staticmethod
    def info(terms: Mapping[str, Tensor]) -> dict[str, Tensor]:
        """``reward/<name>``: every term's unweighted value, for the logs."""
        return {f"reward/{k}": v for k, v in terms.items()}


def check_term_names(given: Mapping[str, Any], known: Mapping[str, Any] | tuple[str, ...], owner: str) -> None:
    """Raise ValueError when ``given`` names a term not in ``known`` (the message lists the known ones)."""
    unknown = sorted(set(given) - set(known))
    if unknown:
        raise ValueError(f"{owner}: unknown term(s) {', '.join(unknown)}; the terms are {', '.join(known)}")


# -------------------------------------------------------------------------------- termination
class TerminationTerms:
    """Named termination terms, OR-ed (module docstring). ``enabled`` (name -> bool, from the params)
    can switch single terms off; an unknown name is an error."""

    def __init__(self, names: tuple[str, ...], enabled: Mapping[str, bool] | None = None, owner: str = "termination_terms"):
        self.enabled: dict[str, bool] = {n: True for n in names}
        if enabled:
            check_term_names(enabled, names, owner)
            self.enabled.update({str(k): bool(v) for k, v in enabled.items()})

    def __call__(self, parts: Mapping[str, Tensor]) -> tuple[Tensor, dict[str, Tensor]]:
        """``(terminated (N,) bool, info)`` with ``terminated/<name>`` for every declared term."""
        if set(parts) != set(self.enabled):
            raise ValueError(f"termination terms {sorted(parts)} do not match the declared {sorted(self.enabled)}")
        out: Tensor | None = None
        for name, on in self.enabled.items():
            if on:
                b = parts[name].bool()
                out = b if out is None else out | b
        if out is None:
            out = torch.zeros_like(next(iter(parts.values())), dtype=torch.bool)
        return out, {f"terminated/{k}": v.float() for k, v in parts.items()}


# ------------------------------------------------------------------------------------- starts
class ReferenceStarts:
    """Reference-state starts on a motion library (module docstring).

    Args:
        library: the clips (their sampling weights are the library's).
        dt: control step, s.
        control_grid: move start times onto the control grid (the reference then is a table lookup,
            :meth:`MotionLibrary.use_control_grid`).
        loops: honour looping clips (a start anywhere in the period); False treats every clip as
            non-looping (VMP's tracker, which jumps to another clip at a clip's end instead).
        start_sampler: optional failure-driven start times within the clip (``sample_times(clips, gen)``).
    """

    def __init__(self, library: MotionLibrary, dt: float, *, control_grid: bool = True, loops: bool = True, start_sampler: Any = None):
        self.library, self.dt = library, float(dt)
        self.control_grid, self.start_sampler = bool(control_grid), start_sampler
        dev = library.device
        self.durations = library.durations64.to(dev)  # float64: a float32 duration can drop the last grid start
        self.loops = library.loops.to(dev) if loops else torch.zeros(len(library.clip_names), dtype=torch.bool, device=dev)

    def sample(self, n: int, generator: torch.Generator) -> tuple[Tensor, Tensor]:
        """``(clip_ids (n,) long, t0 (n,) float64)`` on the library's device."""
        dev = self.durations.device
        clips, times = self.library.sample(n, generator=generator)
        clips = clips.to(dev)
        t0 = times.to(dev, torch.float64)
        if self.start_sampler is not None:
            t0 = self.start_sampler.sample_times(clips, generator).to(dev)
        dur = self.durations[clips]
        loops = self.loops[clips]
        t0 = torch.minimum(t0, torch.where(loops, dur, (dur - self.dt).clamp_min(0.0)))
        if self.control_grid:
            t0 = grid_start_times(t0, dur, loops, self.dt)
        return clips, t0

    def clip_over(self, clip_ids: Tensor, t_next: Tensor) -> Tensor:
        """(N,) bool: a non-looping clip has no frame at ``t_next`` (the episode must end)."""
        return ~self.loops[clip_ids] & (t_next > self.durations[clip_ids] + 1e-6)


# ----------------------------------------------------------------------------------- episodes
class EpisodeBook:
    """Per-env episode counters and the end of every step (module docstring).

    ``steps`` (N,) long counts the steps of the current episode (1 after the first step);
    ``returns`` (N,) float64 its summed reward."""

    def __init__(self, num_envs: int, device: Any = "cpu"):
        self.num_envs = int(num_envs)
        self.steps = torch.zeros(self.num_envs, dtype=torch.long, device=device)
        self.returns = torch.zeros(self.num_envs, dtype=torch.float64, device=device)

    def start(self, ids: Tensor) -> None:
        """Envs ``ids`` begin a new episode."""
        self.steps[ids] = 0
        self.returns[ids] = 0.0

    def conclude(
        self,
        reward: Tensor,
        terminated: Tensor,
        truncated: Tensor,
        observe: Callable[[Tensor | None], Tensor],
        reset: Callable[[Tensor], None],
        *,
        info: dict[str, Any] | None = None,
        on_finish: Callable[[Tensor, Tensor], dict[str, Tensor] | None] | None = None,
        count_step: bool = True,
    ) -> StepResult:
        """End a step: ``reward`` (N,) is added to the returns (and the step counted, unless the env
        counted it already with :meth:`tick`); ``truncated`` loses the envs that ``terminated``;
        ``final_obs = observe(None)``; finished envs are reported (``return``, ``length``,
        ``success``, plus what ``on_finish(ids, terminated[ids])`` adds), reset with ``reset(ids)``
        and re-observed with ``observe(ids)``."""
        if count_step:
            self.tick()
        terminated = terminated.bool()
        truncated = truncated.bool() & ~terminated
        self.returns += reward.to(self.returns)
        done = terminated | truncated
        final_obs = observe(None)
        obs = final_obs
        episodes: dict[str, Tensor] = {}
        if bool(done.any()):
            ids = done.nonzero().squeeze(-1)
            episodes = {
                "return": self.returns[ids].float().cpu(),
                "length": self.steps[ids].float().cpu(),
                "success": (~terminated[ids]).float().cpu(),
            }
            if on_finish is not None:
                episodes.update(on_finish(ids, terminated[ids]) or {})
            reset(ids)
            obs = final_obs.clone()
            obs[ids] = observe(ids)
        return StepResult(
            obs=obs.clone(),
            reward=reward.float(),
            terminated=terminated.clone(),
            truncated=truncated.clone(),
            final_obs=final_obs,
            info=dict(info or {}),
            episodes=episodes,
        )

    def tick(self) -> None:
        """Count one step of every env (for envs that need the new count before :meth:`conclude`)."""
        self.steps += 1

    def state_dict(self) -> dict[str, Tensor]:
        return {"steps": self.steps.cpu().clone(), "returns": self.returns.cpu().clone()}

    def load_state_dict(self, state: Mapping[str, Tensor]) -> None:
        dev = self.steps.device
        steps, returns = state["steps"], state["returns"]
        if tuple(steps.shape) != (self.num_envs,) or tuple(returns.shape) != (self.num_envs,):
            raise ValueError(f"episode counters of shape {tuple(steps.shape)}, expected ({self.num_envs},)")
        self.steps = steps.to(dev, torch.long).clone()
        self.returns = returns.to(dev, torch.float64).clone()


__all__ = ["EpisodeBook", "ReferenceStarts", "RewardTerms", "TerminationTerms", "check_term_names"]
