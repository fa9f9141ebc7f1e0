"""The ``inbetween`` task (hybrid-RVQ paper Sec. 6.3.1 / App. C.1, Eqs. 12-14): reach
keyframes from the motion library at irregular intervals.

Episode. A ``sequence_steps``-long window of a library clip ([P] 4 s = 120 control steps): the env
draws a start frame (clip, time) and :meth:`start_state` moves its time back, when needed, so that
the whole window fits in a non-looping clip (a clip shorter than the window holds its last frame
at the end); the humanoid starts in the window's first frame. The episode lasts the window
(``episode_steps = sequence_steps``).

Keyframes. ``num_keyframes`` frames of the window ([DEFAULT] 5 including its first and last frame,
3 interior ones at distinct uniformly drawn steps, so the intervals are irregular; App. C.1 says 4,
Table 2 says 5 with 1-s mean intervals). ``keyframe``: ``"full_body"`` (every body's position and
rotation, [P]) or ``"root"`` (the root's only). The paper's "zero-velocity poses" bias is not
reproduced.

Observation ([P] Eqs. 12-13). For the current interval (start keyframe ``f_s``, goal keyframe
``f_g``) and each keyframe body ``j``: ``p_j - p_{f,j}`` and ``theta_j (-) theta_{f,j}``, both in the
root's heading frame ([DEFAULT]; the paper: global): positions rotated by the inverse heading ``h^-1``,
rotation differences ``h^-1 (theta theta_f^-1) h`` (``(-)`` = ``theta theta_f^-1``, [DEFAULT], w >= 0)::

    g_hat = [p_bar_{f_s}, theta_bar_{f_s}, p_bar_{f_g}, theta_bar_{f_g}]   in R^{2 J 7}

plus the time to arrival ``tta`` (control steps to ``f_g``) as a sinusoidal encoding
``e_{2i} = sin(tta / 10000^{2i/d})``, ``e_{2i+1} = cos(...)`` (``time_encoding``): ``"add"`` ([P] as
printed: ``g = g_hat + e``, ``d = dim g_hat``) or ``"concat"`` (``e`` of ``time_encoding_dim`` appended).

Reward ([P] Eq. 14, kernels of Eq. 10)::

    r = 0.1 r_root + 0.65 r_q + 0.1 r_alpha + 0.15 r_ee
    r_root = exp(-10 ||p_root - p~_root||^2), r_q = exp(-2 ||q - q~||^2),
    r_alpha = exp(-0.5 ||qdot - qdot~||^2), r_ee = exp(-40 sum_ee ||p_ee - p~_ee||^2)

(``q`` the hinge angles; ``ee`` hands and feet; weights normalized by their sum, which is 1 in the
paper; the paper writes r_omega for Eq. 10's r_alpha, a notation slip). ``reward_target``:
``"trajectory"`` ([P]: dense, against the ground-truth clip at every step) or ``"keyframes"`` (the
same reward against each keyframe at its step, 0 at the other steps: keyframes only, no ground
truth in between; ``max_reward`` is then ``(num_keyframes - 1) / sequence_steps`` so that the
normalized return is 1 when every keyframe is matched exactly). With ``keyframe: root`` the reward is
``r_root`` alone. ``r`` is in (0, 1].

Termination (``termination``): ``"paper"`` ([P], as imitation) a tracked body (all bodies, or the
root for root keyframes) farther than ``termination_distance`` (0.5 m) from the ground truth at the
current step (``distance_reduce``: ``"max"`` any body, [P] "any body"; ``"mean"`` the PHC/UHC
mean-over-bodies rule); ``"fall"`` the shared fall test; ``"both"``.

Hook: ``step(state)`` advances the step counters.

Metrics (since the last :meth:`InbetweenTask.metrics`). A keyframe is *evaluated* at its step (the
reward computation of the state at that step; the first keyframe is the start and is not
evaluated); it is *hit* when its error is at most ``success_radius``:

* ``keyframe_gmpjpe_mm``: mean over evaluated keyframes of the mean body position error, mm
  ([P] Table 2 "Only Keyframes" G-MPJPE; root keyframes: the root error);
* ``keyframe_mpjpe_mm``: the same, root-relative (full-body keyframes only);
* ``keyframe_root_error``: mean root position error at the evaluated keyframes, m;
* ``keyframe_success_rate``: hit / evaluated keyframes;
* ``full_gmpjpe_mm``: mean body position error against the ground truth over every step, mm ("Full
  Frames");
* ``reward``: mean reward; ``steps``: number of control steps (a sum);
* ``success_rate``: fraction of the finished episodes (with at least one step) in which every
  keyframe after the first was evaluated and hit; ``episodes``: their number (a sum).
"""

from __future__ import annotations

from typing import Any

import torch
from mocap.interfaces import Task
from mocap.observations import world_to_heading
from mocap.rotations import (
    heading_quat,
    heading_quat_inv,
    quat_conjugate,
    quat_mul,
    quat_standardize,
)
from mocap.skeleton import Skeleton
from mocap.state import HumanoidState, MotionFrames, SimState
from mocap_tasks.common import TaskBase
from torch import Tensor
from mocap_tasks.task_params import InbetweenParams

__all__ = [
    "InbetweenParams",
    "InbetweenTask",
    "inbetween_reward",
    "keyframe_goal",
    "make_inbetween",
    "time_encoding",
]


def time_encoding(tta: Tensor, dim: int, base: float = 10000.0) -> Tensor:
    """(N, dim) ``e_{2i} = sin(tta / base^{2i/dim})``, ``e_{2i+1} = cos(...)`` (the last sine alone for odd ``dim``)."""
    i = torch.arange((dim + 1) // 2, dtype=torch.float64, device=tta.device)
    freq = base ** (-2.0 * i / dim)
    ang = tta.to(torch.float64)[:, None] * freq
    out = torch.stack((torch.sin(ang), torch.cos(ang)), -1).reshape(tta.shape[0], -1)
    return out[:, :dim]


def keyframe_goal(root_rot: Tensor, pos: Tensor, rot: Tensor, key_pos: Tensor, key_rot: Tensor) -> Tensor:
    """(N, J 7) ``[h^-1 (p - p_f) (J 3) | h^-1 (theta theta_f^-1) h (J 4)]`` for bodies (N, J, 3/4)."""
    n, j = pos.shape[:2]
    dp = world_to_heading(root_rot, pos - key_pos).reshape(n, -1)
    h = heading_quat(root_rot)[:, None].expand(n, j, 4)
    h_inv = heading_quat_inv(root_rot)[:, None].expand(n, j, 4)
    dq = quat_mul(h_inv, quat_mul(quat_mul(rot, quat_conjugate(key_rot)), h))
    return torch.cat((dp, quat_standardize(dq).reshape(n, -1)), -1)


def inbetween_reward(
    sim: HumanoidState,
    ref: HumanoidState,
    ee_index: Tensor,
    weights: tuple[float, float, float, float] = (0.1, 0.65, 0.1, 0.15),
    scales: tuple[float, float, float, float] = (10.0, 2.0, 0.5, 40.0),
    root_only: bool = False,
) -> Tensor:
    """(N,) Eq. 14 (module docstring): ``sum_i w_i exp(-k_i err_i) / sum_i w_i``; ``root_only``: ``r_root``."""
    d_root = sim.root_pos - ref.root_pos
    r_root = torch.exp(-scales[0] * (d_root * d_root).sum(-1))
    if root_only:
        return r_root
    dq = sim.dof_pos - ref.dof_pos.to(sim.dof_pos)
    dv = sim.dof_vel - ref.dof_vel.to(sim.dof_vel)
    de = sim.body_pos[:, ee_index] - ref.body_pos[:, ee_index].to(sim.body_pos)
    terms = (
        r_root,
        torch.exp(-scales[1] * (dq * dq).sum(-1)),
        torch.exp(-scales[2] * (dv * dv).sum(-1)),
        torch.exp(-scales[3] * (de * de).sum((-1, -2))),
    )
    total = sum(w * t for w, t in zip(weights, terms))
    return total / sum(weights)  # type: ignore[return-value]


class InbetweenTask(TaskBase, Task):
    """The ``inbetween`` task (module docstring)."""

    def __init__(
        self,
        params: InbetweenParams,
        *,
        skeleton: Skeleton,
        num_envs: int,
        device: Any = "cpu",
        seed: int | None = None,
        motions: Any = None,
    ):
        self.params = p = params
        self._setup(p.fall, skeleton, num_envs, device, p.seed if seed is None else seed)
        self.sim_overrides = {}
        self.episode_steps = p.sequence_steps
        self.max_reward = 1.0 if p.reward_target == "trajectory" else (p.num_keyframes - 1) / p.sequence_steps
        names = tuple(skeleton.body_names)
        ee = p.end_effectors or tuple(n for n in names if "hand" in n.lower() or "foot" in n.lower())
        for n in ee:
            if n not in names:
                raise ValueError(f"skeleton {skeleton.name!r} has no body {n!r}")
        self.ee_index = torch.tensor([names.index(n) for n in ee], dtype=torch.long)
        self.root_only = p.keyframe == "root"
        self.key_bodies = 1 if self.root_only else skeleton.num_bodies
        ghat = 2 * self.key_bodies * 7
        self.goal_dim = ghat + (p.time_encoding_dim if p.time_encoding == "concat" else 0)
        self.library: Any = motions
        N, dev, K, B = self.num_envs, self.device, p.num_keyframes, self.key_bodies
        self.clip = torch.zeros(N, dtype=torch.long, device=dev)
        self.t0 = torch.zeros(N, dtype=torch.float64, device=dev)
        self.key_steps = torch.zeros(N, K, dtype=torch.long, device=dev)
        self.key_pos = torch.zeros(N, K, B, 3, dtype=torch.float64, device=dev)
        self.key_rot = torch.zeros(N, K, B, 4, dtype=torch.float64, device=dev)
        self.key_rot[..., 0] = 1.0
        self.hits = torch.zeros(N, dtype=torch.long, device=dev)
        self._episode_stats = {"episodes": 0.0, "success": 0.0}

    # ----------------------------------------------------------------------------- motions
    def attach_motions(self, library: Any) -> None:
        """Keep the env's motion library (keyframes and ground truth)."""
        self.library = library

    def _need_library(self) -> Any:
        if self.library is None:
            raise RuntimeError("the inbetween task needs the motion library: attach_motions(library) (the task env does)")
        return self.library

    def reference(self, ids: Tensor, steps: Tensor) -> MotionFrames:
        """Ground-truth frames of envs ``ids`` at window steps ``steps`` (same length)."""
        lib = self._need_library()
        t = self.t0[ids] + steps.to(torch.float64) * self.dt
        return lib.frames(self.clip[ids].to(lib.device), t.to(lib.device))

    def start_state(self, env_ids: Tensor, frames: MotionFrames) -> MotionFrames:
        """The window start: the drawn (clip, time), moved back so the window fits in a non-looping clip."""
        lib = self._need_library()
        ids = self._ids(env_ids)
        clip = torch.as_tensor(frames.clip_ids).long().to(lib.device)
        t = torch.as_tensor(frames.times).to(lib.device, torch.float64)
        span = self.params.sequence_steps * self.dt
        dur = lib.durations.to(lib.device, torch.float64)[clip]
        loops = lib.loops.to(lib.device)[clip]
        t = torch.where(loops, t, torch.minimum(t, dur - span).clamp_min(0.0))
        self.clip[ids] = clip.to(self.device)
        self.t0[ids] = t.to(self.device)
        return lib.frames(clip, t)

    # ------------------------------------------------------------------------------ goals
    def _finish_episodes(self, ids: Tensor) -> None:
        ids = ids[self.progress[ids] > 0]
        if ids.numel() == 0:
            return
        e = self._episode_stats
        e["episodes"] += float(ids.numel())
        e["success"] += float((self.hits[ids] >= self.params.num_keyframes - 1).sum())

    def _select(self, frames: HumanoidState) -> tuple[Tensor, Tensor]:
        if self.root_only:
            return frames.root_pos[:, None], frames.root_rot[:, None]
        return frames.body_pos, frames.body_rot

    def reset(self, env_ids: Tensor, state: SimState) -> None:
        ids = self._ids(env_ids)
        if ids.numel() == 0:
            return
        self._finish_episodes(ids)
        p = self.params
        k, K, T = int(ids.numel()), p.num_keyframes, p.sequence_steps
        inner = torch.rand(k, T - 1, generator=self.generator).argsort(-1)[:, : K - 2] + 1  # distinct steps in [1, T-1]
        steps = torch.cat((torch.zeros(k, 1, dtype=torch.long), inner.sort(-1).values, torch.full((k, 1), T, dtype=torch.long)), -1).to(self.device)
        self.key_steps[ids] = steps
        ref = self.reference(ids.repeat_interleave(K), steps.reshape(-1))
        pos, rot = self._select(ref)
        self.key_pos[ids] = pos.reshape(k, K, self.key_bodies, 3).to(self.key_pos)
        self.key_rot[ids] = rot.reshape(k, K, self.key_bodies, 4).to(self.key_rot)
        self.progress[ids] = 0
        self.hits[ids] = 0

    def step(self, state: SimState) -> None:
        """Advance the step counters."""
        self.progress += 1

    def interval(self) -> tuple[Tensor, Tensor]:
        """(N,) indices of the current interval's start and goal keyframes at the current step."""
        K = self.params.num_keyframes
        j = (self.key_steps <= self.progress[:, None]).sum(-1) - 1
        j = j.clamp(0, K - 2)
        return j, j + 1

    # ------------------------------------------------------------------------ observation
    def observe(self, state: SimState) -> Tensor:
        p = self.params
        n = state.num_envs
        s, g = self.interval()
        ar = torch.arange(n, device=self.device)
        pos, rot = self._select(state)
        dt = state.root_pos
        parts = []
        for f in (s, g):
            kp, kr = self.key_pos[ar, f].to(dt), self.key_rot[ar, f].to(dt)
            parts.append(keyframe_goal(state.root_rot, pos, rot, kp, kr))
        ghat = torch.cat(parts, -1)
        tta = (self.key_steps[ar, g] - self.progress).clamp_min(0).to(dt.device)
        if p.time_encoding == "add":
            return ghat + time_encoding(tta, ghat.shape[-1]).to(ghat)
        return torch.cat((ghat, time_encoding(tta, p.time_encoding_dim).to(ghat)), -1)

    # ----------------------------------------------------------------------------- reward
    def _errors(self, pos: Tensor, key: Tensor) -> tuple[Tensor, Tensor]:
        """(mean body error, root-relative mean body error) between (N, J, 3) positions."""
        g = torch.linalg.vector_norm(pos - key, dim=-1).mean(-1)
        local = torch.linalg.vector_norm((pos - pos[:, :1]) - (key - key[:, :1]), dim=-1).mean(-1)
        return g, local

    def reward(self, state: SimState, actions: Tensor) -> Tensor:
        p = self.params
        n = state.num_envs
        ids = torch.arange(n, device=self.device)
        now = self.progress + 1  # the step of ``state``
        gt = self.reference(ids, now)
        pos, _ = self._select(state)
        full, _ = self._errors(state.body_pos, gt.body_pos.to(state.body_pos))
        self._sums.add("full_gmpjpe_mm", 1000.0 * full)
        # keyframes reached at this step (never the first one)
        at_key = self.key_steps[:, 1:] == now[:, None]  # (N, K - 1)
        is_key = at_key.any(-1)
        kidx = at_key.long().argmax(-1) + 1
        if self.params.reward_target == "trajectory":
            r = inbetween_reward(state, gt, self.ee_index, p.weights, p.scales, self.root_only)
        else:
            key_ref = self.reference(ids, self.key_steps[ids, kidx])
            r = inbetween_reward(state, key_ref, self.ee_index, p.weights, p.scales, self.root_only)
            r = torch.where(is_key.to(r.device), r, torch.zeros_like(r))
        if bool(is_key.any()):
            sel = is_key.nonzero().flatten()
            kp = self.key_pos[sel, kidx[sel]].to(pos)
            g_err, l_err = self._errors(pos[sel.to(pos.device)], kp)
            root_err = torch.linalg.vector_norm(state.root_pos[sel.to(pos.device)] - self.key_pos[sel, kidx[sel], 0].to(pos), dim=-1)
            hit = g_err <= p.success_radius
            self.hits[sel] += hit.to(self.device).long()
            self._sums.add("keyframe_gmpjpe_mm", 1000.0 * g_err)
            if not self.root_only:
                self._sums.add("keyframe_mpjpe_mm", 1000.0 * l_err)
            self._sums.add("keyframe_root_error", root_err)
            self._sums.add("keyframe_success_rate", hit.double())
        self._sums.add("reward", r)
        self._sums.add("steps", float(r.numel()), count=1)
        return r

    def terminated(self, state: SimState) -> Tensor:
        p = self.params
        mode = p.termination
        out = torch.zeros(state.num_envs, dtype=torch.bool, device=state.root_pos.device)
        if mode in ("paper", "both"):
            ids = torch.arange(state.num_envs, device=self.device)
            gt = self.reference(ids, self.progress + 1)
            pos, _ = self._select(state)
            gt_pos, _ = self._select(gt)
            d = torch.linalg.vector_norm(pos - gt_pos.to(pos), dim=-1)
            d = d.max(-1).values if p.distance_reduce == "max" else d.mean(-1)
            out = out | (d > p.termination_distance).to(out.device)
        if mode in ("fall", "both"):
            out = out | self._fallen(state).to(out.device)
        return out

    def metrics(self) -> dict[str, float]:
        out = self._sums.pop(totals=("steps",))
        e = self._episode_stats
        if e["episodes"] > 0:
            out["episodes"] = e["episodes"]
            out["success_rate"] = e["success"] / e["episodes"]
        self._episode_stats = {k: 0.0 for k in e}
        return out


def make_inbetween(
    params: InbetweenParams,
    *,
    skeleton: Skeleton,
    num_envs: int,
    device: Any = "cpu",
    seed: int | None = None,
    motions: Any = None,
    **_: Any,
) -> InbetweenTask:
    """Registry factory of the ``inbetween`` task (``motions``: the env's motion library, optional; the
    task env also passes it through :meth:`InbetweenTask.attach_motions`)."""
    return InbetweenTask(params, skeleton=skeleton, num_envs=num_envs, device=device, seed=seed, motions=motions)
