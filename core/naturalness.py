"""How natural a rollout's motion is, measured against the motion data (issue 61; PULSE Sec. 5's claim
that a latent-space policy moves in a human-like way while a scratch policy "could lead to unnatural
behavior" becomes numbers).

A :class:`NaturalnessRecorder` is fed the humanoid's state every control step (a task policy's
rollout in ``mocap task-eval``, a clip replayed kinematically in the tests) and reports, over every
frame of every episode (a new episode breaks the pairs and windows that would straddle it):

* ``mm_distance``: motion matching (hybrid_rvq Eq. 8, the features of :mod:`mocap.generation`):
  each transition ``(s_{t-1}, s_t)`` of PHC proprioception (heading frame) is matched to its nearest
  transition of the motion data at the control rate, features standardized by the data's mean and
  std; the mean over **all** transitions of the squared distance divided by the feature count
  (dimensionless; 0 for a replayed clip). Unlike generation's ``match_distance`` nothing is filtered
  out first, so a policy that leaves the data is not flattered.
* ``mm_within``: the share of transitions whose squared distance per feature is at most
  ``match_threshold`` (generation's ``filter_threshold``, default 1.0).
* ``foot_skating``: mean horizontal speed (m/s) of a foot (``skeleton.feet``) over consecutive frames
  in which it is in contact with the ground at both: its body origin at most ``contact_margin`` above
  its rest-pose height (:func:`mocap.humanoids.common.rest_root_height`), so that a simulated rollout
  and a kinematic replay use the same rule.
* ``root_jerk``: mean norm of the root position's third finite difference over four consecutive
  frames, divided by dt³ (m/s³).
* ``crouch_share``: share of frames with the root (pelvis) below ``crouch_fraction`` × its rest-pose
  height (default 0.8: 0.71 m for ``amp``);
* ``realism`` (with a judge, :mod:`mocap.realism`): the fixed judge's mean score of the transitions,
  in (0, 1), near 1 for the motion data.

Falls are the task env's terminations (``terminated_share`` in task-eval). Every value is NaN when
the rollout had no frame, pair or window to measure it on.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Any

import torch
from torch import Tensor

from mocap.observations import SixD, proprioception
from mocap.skeleton import Skeleton
from mocap.state import HumanoidState

#: the keys :meth:`NaturalnessRecorder.result` reports (display names and units: ``mocap.metric_display.TASK_EVAL_INFO``)
NATURALNESS_KEYS: tuple[str, ...] = ("mm_distance", "mm_within", "foot_skating", "root_jerk", "crouch_share")


@dataclass(frozen=True)
class NaturalnessParams:
    """``match_threshold``: squared distance per feature within which a transition matches the data;
    ``contact_margin``: m above a foot's rest height that still counts as contact; ``crouch_fraction``:
    of the rest-pose root height, below which a frame counts as crouched."""

    match_threshold: float = 1.0
    contact_margin: float = 0.03
    crouch_fraction: float = 0.8


def nearest_transitions(generated: Tensor, dataset: Tensor, chunk: int = 4096) -> tuple[Tensor, Tensor]:
    """``(best, idx)`` (M,): the squared distance of each generated transition to its nearest dataset
    transition and that transition's index, in features standardized by the dataset's mean and std
    (hybrid_rvq Eq. 8's matching; :func:`mocap.generation_eval.motion_matching` filters on it too)."""
    mean, std = dataset.mean(0), dataset.std(0).clamp_min(1e-6)
    g, d = (generated - mean) / std, (dataset - mean) / std
    best = torch.empty(len(g), dtype=g.dtype)
    idx = torch.empty(len(g), dtype=torch.long)
    for s in range(0, len(g), chunk):
        best[s : s + chunk], idx[s : s + chunk] = torch.cdist(g[s : s + chunk], d).pow(2).min(-1)
    return best, idx


def nearest_per_feature(generated: Tensor, dataset: Tensor, chunk: int = 4096) -> Tensor:
    """(M,) :func:`nearest_transitions`' squared distance divided by the feature count F."""
    return nearest_transitions(generated, dataset, chunk)[0] / generated.shape[1]


class NaturalnessRecorder:
    """Accumulates the module docstring's measurements over a batch of N envs, step by step."""

    def __init__(self, skeleton: Skeleton, dataset: Tensor, dt: float, params: NaturalnessParams | None = None, sixd: SixD = "zhou", judge: Any = None):
        """``judge``: a :class:`mocap.realism.RealismJudge` for ``realism`` (None: not reported)."""
        from mocap.humanoids.common import rest_body_positions, rest_root_height

        self.judge = judge
        self.params = params or NaturalnessParams()
        self.dataset, self.dt, self.sixd = dataset.float(), float(dt), sixd
        self.feet = [skeleton.body_names.index(f) for f in skeleton.feet]
        rest, root_h = rest_body_positions(skeleton), rest_root_height(skeleton)
        self.contact_height = torch.tensor([root_h + float(rest[i][2]) + self.params.contact_margin for i in self.feet])
        self.crouch_height = self.params.crouch_fraction * root_h
        self._features: list[Tensor] = []
        self._prev: Tensor | None = None
        self._roots: list[Tensor] = []  # the last four root positions, oldest first
        self._run: Tensor | None = None  # per env: frames in the current episode so far
        self._feet_prev: Tensor | None = None
        self._sums = {"skating": 0.0, "skating_n": 0, "jerk": 0.0, "jerk_n": 0, "crouch": 0, "frames": 0}

    def add(self, state: HumanoidState, fresh: Tensor | None = None) -> None:
        """One frame of the N envs; ``fresh`` (N,) bool marks envs whose episode starts at this frame
        (after a reset), so no pair or window crosses the boundary."""
        n = state.root_pos.shape[0]
        fresh = torch.zeros(n, dtype=torch.bool) if fresh is None else fresh.bool().cpu()
        feat = proprioception(state, self.sixd).float().cpu()
        feet = state.body_pos[:, self.feet].float().cpu()
        root = state.root_pos.float().cpu()
        run = torch.ones(n, dtype=torch.long) if self._run is None else torch.where(fresh, 1, self._run + 1)
        if self._prev is not None and self._feet_prev is not None:
            pair = run >= 2
            self._features.append(torch.cat([self._prev, feat], -1)[pair])
            contact = (feet[..., 2] <= self.contact_height) & (self._feet_prev[..., 2] <= self.contact_height) & pair[:, None]
            speed = (feet[..., :2] - self._feet_prev[..., :2]).norm(dim=-1) / self.dt
            self._sums["skating"] += float(speed[contact].sum())
            self._sums["skating_n"] += int(contact.sum())
        self._roots = [*self._roots[-3:], root]
        if len(self._roots) == 4:
            window = run >= 4
            x0, x1, x2, x3 = self._roots
            jerk = (x3 - 3 * x2 + 3 * x1 - x0).norm(dim=-1) / self.dt**3
            self._sums["jerk"] += float(jerk[window].sum())
            self._sums["jerk_n"] += int(window.sum())
        self._sums["crouch"] += int((root[:, 2] < self.crouch_height).sum())
        self._sums["frames"] += n
        self._prev, self._feet_prev, self._run = feat, feet, run

    def result(self) -> dict[str, float]:
        """The module docstring's keys (NaN where nothing was measured)."""
        s = self._sums
        out = {k: math.nan for k in NATURALNESS_KEYS}
        transitions = torch.cat(self._features) if self._features else torch.zeros(0)
        if transitions.numel():
            per_feature = nearest_per_feature(transitions, self.dataset)
            out["mm_distance"] = float(per_feature.mean())
            out["mm_within"] = float((per_feature <= self.params.match_threshold).double().mean())
            if self.judge is not None:
                out["realism"] = float(self.judge.score(transitions).mean())
        if s["skating_n"]:
            out["foot_skating"] = s["skating"] / s["skating_n"]
        if s["jerk_n"]:
            out["root_jerk"] = s["jerk"] / s["jerk_n"]
        if s["frames"]:
            out["crouch_share"] = s["crouch"] / s["frames"]
        return out


__all__ = ["NATURALNESS_KEYS", "NaturalnessParams", "NaturalnessRecorder", "nearest_per_feature", "nearest_transitions"]
