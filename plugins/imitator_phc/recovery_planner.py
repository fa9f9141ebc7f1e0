"""A get-up planner: recovery from a fall by *tracking* a get-up clip, then walking back.

Not PHC+'s P(F). PHC (Sec. 3.2) learns recovery as a primitive of its own, and its official code
first trains that primitive to get up with an AMP reward alone (``humanoid_im_getup.py``); on these
cores that phase learned nothing in 3M steps (``bench/results/pmcp_getup_from_v2``). An imitator
that already tracks the motion set's get-up clips can get up instead by being *given* one, started
where and how the humanoid lies. This planner rewrites the reference an imitator receives, per
trial, in three modes:

1. **get up**: when the root has been lower than ``fallen_ratio`` x the standing root height for
   ``fallen_steps`` control steps (at once when a trial starts down), the get-up clip whose first
   frame's root orientation is closest to the humanoid's, up to a turn about the vertical
   (:func:`mocap.motion.transform.best_yaw`), is played from its start, turned by that angle and
   moved so that its first root lies under the humanoid's root (:func:`~mocap.motion.transform.yaw_frames`);
   when the clip ends before the humanoid is up (root at ``up_ratio`` x the standing height), its
   last frame is held at rest, and a humanoid still down ``fallen_steps`` after that starts another
   (counted from the get-up's start: the clip's duration plus ``fallen_steps`` control steps). With
   ``getup_clock: pose`` the clip's clock is paced by the humanoid: each step the clip time whose
   pose is closest to the humanoid's (:func:`pose_features`, searched within ``pose_back_s``
   before and ``pose_ahead_s`` after the clock) is found, and the clock speeds up while the humanoid
   is ahead of it (and, with ``pose_lead_s``, slows down when it leads that pose by more than that;
   :func:`pose_clock_rate`), so the reference keeps pace with a humanoid that gets up faster than
   the clip;
2. **approach** (with ``approach_clip``, default ``walk``): after the get-up, while the root is
   farther than ``approach_distance`` from the reference's root, the looping approach clip is
   played, its root placed at the humanoid's, facing the humanoid's heading turned toward the
   reference (its direction of travel over the next second of the clip) by at most ``max_turn_deg``,
   re-aimed every ``replan_steps`` steps (the clip's time runs on, so
   the gait's phase is continuous); it starts at the time of the clip whose joint angles are closest
   to the get-up's last frame, played slowly (``approach_start_rate``, velocities scaled alike) and
   sped up to its own pace over ``approach_ramp_s``;
3. **track**: the reference the planner was given.

The planner is part of the *driver* (``mocap recover --planner getup``), not of the policy: the
recovery metric is still measured against the protocol's reference, and a result obtained with it
says so (``planner`` in the JSON).
"""

from __future__ import annotations

import math
from dataclasses import replace
from typing import Any

import torch
from torch import Tensor

from mocap.getup_starts import GetUpClips
from mocap_phc.planner_params import GetUpPlannerParams
from mocap.motion.transform import frames_at_rate, yaw_frames
from mocap.rotations import heading_angle, quat_apply, quat_conjugate
from mocap.state import HUMANOID_FIELDS, MotionFrames

TRACK, GETUP, APPROACH = 0, 1, 2
MIN_RAMP_S = 1e-9  # approach ramps shorter than this are no ramp (:meth:`GetUpPlanner._warp`)
HEIGHT_WEIGHT = 10.0  # 1/m^2: in pose_features, 0.1 m of root height weighs as much as a 0.32 rad RMS joint error
POSE_TIE = 1e-4  # per second away from the clock: among equally close poses (a still segment) the one nearest the clock


def pose_clock_rate(lead: Tensor, lead_s: float | None, tau_s: float, max_rate: float) -> Tensor:
    """The rate a pose-clocked get-up clip runs at when the clock leads the humanoid's matched pose
    by ``lead`` s: 1 for a lead in [0, lead_s]; beyond it falling linearly to 0 at lead_s + tau_s;
    below 0 (the humanoid ahead) rising linearly, 1 - lead / tau_s, up to ``max_rate``. ``lead_s``
    None: 1 for every lead >= 0 (the clock never slows)."""
    lead_s = math.inf if lead_s is None else lead_s
    behind = (1.0 - (lead - lead_s) / tau_s).clamp(min=0.0)
    ahead = (1.0 - lead / tau_s).clamp(max=max_rate)
    return torch.where(lead > lead_s, behind, torch.where(lead < 0, ahead, torch.ones_like(lead)))


def pose_features(root_pos: Tensor, root_rot: Tensor, dof_pos: Tensor) -> Tensor:
    """(N, D + 4) features of a pose that do not change with a turn about the vertical or a move on
    the ground: the joint angles over sqrt(D), the world up axis in the root's frame, and the root
    height times sqrt(HEIGHT_WEIGHT); the squared distance of two is the mean squared joint-angle
    difference (rad^2) + the squared up-axis difference + HEIGHT_WEIGHT x the squared height difference."""
    rot = root_rot.double()
    up = quat_apply(quat_conjugate(rot), torch.tensor([0.0, 0.0, 1.0], dtype=torch.float64).expand(rot.shape[0], 3))
    dof = dof_pos.double()
    return torch.cat([dof / math.sqrt(max(1, dof.shape[-1])), up, root_pos[:, 2:3].double() * math.sqrt(HEIGHT_WEIGHT)], dim=-1)


def standing_height(library: Any) -> float:
    """The median first-frame root height over the clips: the height of a humanoid standing."""
    n = int(library.num_clips)
    f = library.frames(torch.arange(n), torch.zeros(n, dtype=library.dtype, device=library.device))
    return float(f.root_pos[:, 2].double().median())


def select(mask: Tensor, a: MotionFrames, b: MotionFrames) -> MotionFrames:
    """Row-wise ``a if mask else b`` over every state field, ``clip_ids``, ``times`` and ``ahead``."""

    def pick(x: Tensor, y: Tensor) -> Tensor:
        m = mask.to(x.device).reshape(-1, *([1] * (x.dim() - 1)))
        return torch.where(m, x, y.to(x))

    kw: dict[str, Any] = {k: pick(getattr(a, k), getattr(b, k)) for k in HUMANOID_FIELDS}
    kw["clip_ids"] = pick(a.clip_ids, b.clip_ids) if a.clip_ids.numel() and b.clip_ids.numel() else a.clip_ids
    kw["times"] = pick(a.times, b.times) if a.times.numel() and b.times.numel() else a.times
    kw["ahead"] = tuple(select(mask, x, y) for x, y in zip(a.ahead, b.ahead, strict=True))
    return replace(a, **kw)


class GetUpPlanner:
    """Per-trial reference rewriting for ``n`` trials (module docstring). Call :meth:`reference`
    once per control step ``k`` = 1, 2, ... with the simulated state before the step and the
    reference the driver would give; it returns the reference to give the imitator instead."""

    def __init__(self, library: Any, params: GetUpPlannerParams, n: int, dt: float, steps: int = 1):
        names = list(library.clip_names)
        self.getups = GetUpClips(library, params.clips, who="get-up planner")
        self.approach: int | None = None
        if params.approach_clip is not None:
            if params.approach_clip not in names:
                raise ValueError(f"get-up planner: no approach clip {params.approach_clip!r} (clips: {', '.join(names)})")
            self.approach = names.index(params.approach_clip)
            if not bool(library.loops[self.approach]):
                raise ValueError(f"get-up planner: the approach clip {params.approach_clip!r} must loop")
            self._entry = self._entry_phases(library, self.approach)
        self.lib, self.p, self.n, self.dt, self.steps = library, params, n, float(dt), int(steps)
        #: root height of a standing humanoid (:func:`standing_height`) and the fallen threshold, m
        self.standing = standing_height(library)
        self.up_ratio = params.up_ratio
        self.fallen_height = params.fallen_ratio * self.standing
        self.mode = torch.full((n,), TRACK, dtype=torch.long)
        self.clip = torch.zeros(n, dtype=torch.long)
        self.t0 = torch.zeros(n, dtype=torch.float64)  # clip time at the segment's step `k0`
        self.k0 = torch.zeros(n, dtype=torch.long)
        self.began = torch.zeros(n, dtype=torch.long)  # the step before the current get-up's first reference
        self.pose_rate = torch.ones(n, dtype=torch.float64)  # getup_clock 'pose': the rate of the current step
        self.yaw = torch.zeros(n, dtype=torch.float64)
        self.pivot = torch.zeros(n, 2, dtype=torch.float64)
        self.target = torch.zeros(n, 2, dtype=torch.float64)
        self.low = torch.zeros(n, dtype=torch.long)
        self.aimed = torch.zeros(n, dtype=torch.long)  # the step the approach was last aimed at
        #: how many get-ups each trial started
        self.getups_started = torch.zeros(n, dtype=torch.long)

    def _entry_phases(self, library: Any, approach: int) -> Tensor:
        """(clips,) the approach clip's time whose joint angles are closest to each get-up clip's last
        frame (on a 30 Hz grid of one cycle): the approach starts from the pose the get-up ends in."""
        dur = float(library.durations[approach])
        grid = torch.arange(0.0, dur, 1.0 / 30.0, dtype=torch.float64)
        cyc = library.frames(torch.full((len(grid),), approach, dtype=torch.long), grid.to(library.dtype)).dof_pos.double().cpu()
        out = torch.zeros(int(library.num_clips), dtype=torch.float64)
        for c in self.getups.clips.tolist():
            end = library.frames(torch.tensor([c]), library.durations[c : c + 1].to(library.dtype)).dof_pos.double().cpu()
            out[c] = grid[int(((cyc - end) ** 2).sum(-1).argmin())]
        return out

    def _warp(self, e: Tensor) -> tuple[Tensor, Tensor]:
        """(clip time elapsed, rate) after ``e`` s of an approach: the rate rises linearly from
        ``approach_start_rate`` to 1 over ``approach_ramp_s``, then stays 1. A ramp shorter than
        ``MIN_RAMP_S`` is none (a subnormal ramp made ``within / ramp`` inexact: rates above 1)."""
        r0, ramp = self.p.approach_start_rate, self.p.approach_ramp_s
        if ramp < MIN_RAMP_S:
            return e, torch.ones_like(e)
        within = e.clamp(max=ramp)
        tau = r0 * within + (1.0 - r0) * within**2 / (2.0 * ramp) + (e - ramp).clamp(min=0.0)
        return tau, (r0 + (1.0 - r0) * within / ramp)

    def _clip_time(self, k: int) -> Tensor:
        e = (k - self.k0).double() * self.dt
        tau, _ = self._warp(e)
        return self.t0 + torch.where(self.mode == APPROACH, tau, e)

    def _rate(self, k: int) -> Tensor:
        _, rate = self._warp((k - self.k0).double() * self.dt)
        return torch.where(self.mode == APPROACH, rate, torch.ones_like(rate))

    def _start_getup(self, rows: Tensor, k: int, root_pos: Tensor, root_rot: Tensor) -> None:
        clip, yaw, pivot, target = self.getups.lay_onto(root_pos[rows], root_rot[rows])
        self.mode[rows] = GETUP
        self.clip[rows] = clip
        self.t0[rows] = 0.0
        self.k0[rows] = k - 1  # the reference of step k is the clip one control step in
        self.began[rows] = k - 1
        self.pose_rate[rows] = 1.0
        self.yaw[rows] = yaw
        self.pivot[rows] = pivot
        self.target[rows] = target
        self.getups_started[rows] += 1

    def _aim(self, rows: Tensor, k: int, root_pos: Tensor, root_rot: Tensor, goal: Tensor, restart: Tensor) -> None:
        """Point the approach clip from the humanoid's root toward ``goal`` (xy) for ``rows``;
        ``restart`` rows start the clip from its beginning, the others keep its time running."""
        assert self.approach is not None
        t = torch.where(restart, self._entry[self.clip[rows]], self._clip_time(k)[rows])
        clip = torch.full((len(rows),), self.approach, dtype=torch.long)
        now = self.lib.frames(clip, t.to(self.lib.dtype))
        later = self.lib.frames(clip, (t + 1.0).to(self.lib.dtype))  # the clip's travel direction over the next second
        step = (later.root_pos[:, :2] - now.root_pos[:, :2]).double().cpu()
        to_goal = goal[rows] - root_pos[rows, :2]
        aim = torch.atan2(to_goal[:, 1], to_goal[:, 0]) - torch.atan2(step[:, 1], step[:, 0])  # the clip's travel toward the goal
        face = heading_angle(root_rot[rows]) - heading_angle(now.root_rot.double().cpu())  # the clip facing the humanoid's way
        turn = torch.atan2(torch.sin(aim - face), torch.cos(aim - face))
        limit = math.radians(self.p.max_turn_deg)
        self.mode[rows] = APPROACH
        self.clip[rows] = self.approach
        self.aimed[rows] = k
        new = rows[restart]
        self.t0[new] = t[restart] - self._warp(torch.full((len(new),), self.dt, dtype=torch.float64))[0]
        self.k0[new] = k - 1
        self.yaw[rows] = face + turn.clamp(-limit, limit)
        self.pivot[rows] = now.root_pos[:, :2].double().cpu()
        self.target[rows] = root_pos[rows, :2]

    def matched_times(self, rows: Tensor, now: Tensor, state: Any) -> Tensor:
        """(R,) for ``rows`` in a get-up: the clip time within ``pose_back_s`` before and
        ``pose_ahead_s`` after ``now`` (R,), on the control grid, whose pose (:func:`pose_features`)
        is closest to the humanoid's in ``state`` (ties: the one nearest ``now``)."""
        p, lib, dt = self.p, self.lib, self.dt
        dur = lib.durations.double().cpu()[self.clip[rows]]
        offsets = torch.arange(-round(p.pose_back_s / dt), round(p.pose_ahead_s / dt) + 1, dtype=torch.float64) * dt
        grid = torch.round(now / dt) * dt  # candidates on the clip's control grid, about the clock
        cand = torch.minimum((grid[:, None] + offsets[None]).clamp(min=0.0), dur[:, None])  # (R, J)
        n_rows, n_cand = cand.shape
        clips = self.clip[rows].repeat_interleave(n_cand)
        f = lib.frames(clips.to(lib.device), cand.reshape(-1).to(lib.device, lib.dtype))
        ref = pose_features(f.root_pos.cpu(), f.root_rot.cpu(), f.dof_pos.cpu()).reshape(n_rows, n_cand, -1)
        rows_d = rows.to(state.root_pos.device)
        own = pose_features(state.root_pos[rows_d].cpu(), state.root_rot[rows_d].cpu(), state.dof_pos[rows_d].cpu())
        dist = ((ref - own[:, None]) ** 2).sum(-1) + POSE_TIE * (cand - now[:, None]).abs()
        return cand.gather(1, dist.argmin(1, keepdim=True)).squeeze(1)

    def _pace_by_pose(self, rows: Tensor, k: int, state: Any) -> None:
        """``getup_clock: pose``: the clock's lead over the humanoid's matched pose
        (:meth:`matched_times`) sets the rate the clip runs at this step (:func:`pose_clock_rate`);
        step ``k``'s reference is that rate x one control step on from the clock's current time."""
        p, dt = self.p, self.dt
        now = self._clip_time(k)[rows] - dt  # the clock's time of the state the humanoid is in
        lead = now - self.matched_times(rows, now, state)
        lead = torch.where(lead.abs() < 1e-9, 0.0, lead)  # on the clock up to rounding: rate exactly 1
        rate = pose_clock_rate(lead, p.pose_lead_s, p.pose_tau_s, p.pose_max_rate)
        self.t0[rows] = now + (rate - 1.0) * dt  # so that the clip time of step k is now + rate x dt
        self.k0[rows] = k - 1
        self.pose_rate[rows] = rate

    def reference(self, k: int, state: Any, given: MotionFrames) -> MotionFrames:
        p = self.p
        root_pos = state.root_pos.double().cpu()
        root_rot = state.root_rot.double().cpu()
        goal = given.root_pos[:, :2].double().cpu()
        down = root_pos[:, 2] < self.fallen_height
        self.low = torch.where(down, self.low + 1, torch.zeros_like(self.low))
        dur = self.lib.durations.double().cpu()[self.clip]
        # a get-up whose clip ended fallen_steps ago (its last frame held at rest since) with the humanoid still down
        elapsed = (k - self.began).double() * self.dt  # since the get-up started (its clip time with getup_clock 'time')
        stuck = (self.mode == GETUP) & (elapsed - dur >= p.fallen_steps * self.dt) & down
        start = ((self.mode != GETUP) & ((self.low >= p.fallen_steps) | (down & (k == 1)))) | stuck
        if bool(start.any()):
            self._start_getup(start.nonzero().squeeze(-1), k, root_pos, root_rot)
            dur = self.lib.durations.double().cpu()[self.clip]
        if p.getup_clock == "pose":
            paced = (self.mode == GETUP) & ~start & (self._clip_time(k) - self.dt < dur)
            if bool(paced.any()):
                self._pace_by_pose(paced.nonzero().squeeze(-1), k, state)
        up = root_pos[:, 2] >= self.up_ratio * self.standing
        done = (self.mode == GETUP) & (self._clip_time(k) > dur) & up
        far = torch.linalg.vector_norm(root_pos[:, :2] - goal, dim=-1) > p.approach_distance
        if bool(done.any()):
            walk = done & far if self.approach is not None else torch.zeros_like(done)
            self.mode[done & ~walk] = TRACK
            if bool(walk.any()):
                rows = walk.nonzero().squeeze(-1)
                self._aim(rows, k, root_pos, root_rot, goal, torch.ones(len(rows), dtype=torch.bool))
        arrived = (self.mode == APPROACH) & ~far
        self.mode[arrived] = TRACK
        replan = (self.mode == APPROACH) & ((k - self.aimed) >= p.replan_steps)
        if bool(replan.any()):
            rows = replan.nonzero().squeeze(-1)
            self._aim(rows, k, root_pos, root_rot, goal, torch.zeros(len(rows), dtype=torch.bool))
        planned = self.mode != TRACK
        if not bool(planned.any()):
            return given
        t = self._clip_time(k).clamp(min=0.0)
        t = torch.where(self.mode == GETUP, torch.minimum(t, dur), t)
        lib = self.lib
        frames = lib.frames_ahead(self.clip.to(lib.device), t.to(lib.device, lib.dtype), self.dt, self.steps)
        held = (self.mode == GETUP) & (self._clip_time(k) >= dur)
        if bool(held.any()):  # the get-up's last frame, held at rest until the mode changes
            frames = frames_at_rate(frames, torch.where(held, 0.0, 1.0))
        off_pace = (self.mode == GETUP) & ~held & (self.pose_rate != 1.0) if p.getup_clock == "pose" else torch.zeros_like(held)
        if bool(off_pace.any()):  # a pose-clocked get-up off its own pace: velocities at the rate it is played
            frames = frames_at_rate(frames, torch.where(off_pace, self.pose_rate, 1.0))
        slow = (self.mode == APPROACH) & (self._rate(k) < 1.0)
        if bool(slow.any()):  # an approach starting slowly: the clip's velocities at the rate it is played
            frames = frames_at_rate(frames, torch.where(slow, self._rate(k), 1.0))
        frames = yaw_frames(frames, self.yaw, self.pivot, self.target)
        return select(planned, frames, given)

    def stats(self) -> dict[str, Any]:
        return {
            "getups_started_mean": float(self.getups_started.double().mean()),
            "mode_at_end": {name: int((self.mode == m).sum()) for name, m in (("track", TRACK), ("getup", GETUP), ("approach", APPROACH))},
        }


__all__ = ["APPROACH", "GETUP", "TRACK", "GetUpPlanner", "GetUpPlannerParams", "pose_clock_rate", "pose_features", "select", "standing_height"]
