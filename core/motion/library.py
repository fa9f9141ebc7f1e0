"""The motion library: clips on one skeleton, packed into tensors, sampled at arbitrary times.

At construction every frame of every clip is converted once (float64 on the CPU, then cast to
``dtype`` on ``device``) into everything a simulator state holds:

* ``dof_pos``: :func:`~mocap.kinematics.dofs_from_local_rotations` of the clip's local rotations,
  unwrapped over time within each clip (no 2 pi jumps) and shifted by a multiple of 2 pi so that
  each DoF's mean over the clip lies in (-pi, pi];
* ``local_rot``: the local rotation of every non-root body that *those DoFs* produce (a 1-DoF
  knee drops any off-axis part of a clip's rotation);
* ``body_pos``/``body_rot``: forward kinematics of the root and ``local_rot``, so bodies and DoFs
  agree;
* velocities by **forward differences**: frame ``i`` gets ``(x[i+1] - x[i]) * fps`` for positions
  and DoFs, and :func:`~mocap.rotations.angular_velocity` ``(q[i], q[i+1], 1/fps)`` (world axes)
  for rotations. The last frame of a non-looping clip repeats the previous frame's velocity; the
  last frame of a looping clip is the next cycle's first frame, so it gets frame 0's velocity
  (rotated by the cycle's heading change when ``loop_heading`` is on). With ``velocities=
  "central_smoothed"`` (the motion source's ``velocities`` param) they are PHC's code's instead:
  central differences for positions and DoFs, and both these and the angular velocities smoothed
  by a Gaussian of ``velocity_sigma`` frames within each clip (:mod:`mocap.motion.velocity`).

:meth:`MotionLibrary.frames` evaluates clips at arbitrary times: with ``f = t * fps`` between
frames ``i`` and ``i + 1``, root position, DoFs and all velocities are linearly interpolated, the
root rotation is slerped, and bodies are forward kinematics of the interpolated root and of the
joints' local rotations, each slerped between the frames' (those the frames' DoFs produce). Bodies
and ``dof_pos`` therefore agree exactly at frame times; between frames lerped DoFs and slerped
rotations agree to second order, except where a ball joint passes near its gimbal lock: there a
3-hinge ball's first and last angles can swing by up to pi within one frame (the punch's right
shoulder at frame 24), and the bodies follow the slerp, i.e. the captured motion, not the detour the
lerped angles would take. With ``body_interp="lerp"`` body positions are instead linearly
interpolated and body rotations slerped between the precomputed frames: cheaper, identical at frame
times, and a chord instead of an arc between them (over the bundled clips: mean 1 mm, up to 3 cm
for the 30-60 Hz clips and 16 cm for the 16 Hz backflip).

Time outside a clip: a non-looping clip clamps to ``[0, duration]``. A looping clip (period
``duration``, its last frame being the next cycle's first, see :mod:`mocap.motion.clip`) wraps:
``t = k * duration + t'`` with ``t'`` in ``[0, duration)``, and the root advances by the cycle
offset once per completed cycle, as DeepMimic does: the horizontal root displacement
``root_pos[-1] - root_pos[0]`` (xy), times ``k``, with no change of heading. A hinge whose range spans more
than one turn (the ``amp`` humanoid's shoulders with ``shoulder_turns`` > 0.5) also advances by the
cycle's winding ``2 pi round((q[-1] - q[0]) / 2 pi)`` per cycle, so that its reference stays
continuous where a clip's unwrapped angle ends a full turn from where it began; a hinge limited to
one turn restarts each cycle at its own angles (it could follow neither). With
``loop_heading=True`` the heading change of the cycle ``h = heading(last) - heading(first)`` is also
accumulated: cycle ``k`` is the cycle-0 motion moved by the planar rigid transform ``M^k`` that maps
the first frame's root (xy position and heading) onto the last frame's. The default is off because
the bundled clips' root yaw differs between first and last frame by a few degrees of sway (walk:
about 7 degrees), which would bend a straight walk into a circle.
"""

from __future__ import annotations

import difflib
import math
from dataclasses import dataclass
from typing import Any, Literal, Sequence

import numpy as np
import torch
from torch import Tensor

from mocap.kinematics import dofs_from_local_rotations, forward_kinematics, local_rotations_from_dofs
from mocap.motion.clip import Clip, MotionDataError
from mocap.motion.sources import MotionSet, VelocityMode, check_clip_skeleton
from mocap.motion.transform import yaw_quat
from mocap.motion.velocity import central_differences, gaussian_smooth
from mocap.rotations import angular_velocity, heading_angle, quat_mul, quat_slerp
from mocap.skeleton import Skeleton
from mocap.state import HUMANOID_FIELDS, MotionFrames


@dataclass(frozen=True)
class ClipInfo:
    """Summary of one clip (what ``mocap motions list/show`` print).

    Attributes:
        name, source: clip name and the file it came from.
        num_frames, fps, duration: frame count, frame rate (Hz) and first-to-last-frame time, s.
        loop: the clip wraps around (DeepMimic ``"wrap"``).
        root_height_min, root_height_max: range of the root (pelvis) height, m.
        distance: horizontal path length of the root over the clip, m.
        displacement: straight-line horizontal distance from the first to the last root position, m
            (for a looping clip, the length of the cycle offset).
    """

    name: str
    source: str
    skeleton: str
    num_frames: int
    fps: float
    duration: float
    loop: bool
    root_height_min: float
    root_height_max: float
    distance: float
    displacement: float

    @classmethod
    def of(cls, clip: Clip) -> "ClipInfo":
        xy = np.asarray(clip.root_pos)[:, :2]
        z = np.asarray(clip.root_pos)[:, 2]
        return cls(
            name=clip.name,
            source=clip.source,
            skeleton=clip.skeleton,
            num_frames=clip.num_frames,
            fps=float(clip.fps),
            duration=float(clip.duration),
            loop=bool(clip.loop),
            root_height_min=float(z.min()),
            root_height_max=float(z.max()),
            distance=float(np.linalg.norm(np.diff(xy, axis=0), axis=-1).sum()),
            displacement=float(np.linalg.norm(xy[-1] - xy[0])),
        )


def _segment_ids(lengths: Tensor) -> Tensor:
    return torch.repeat_interleave(torch.arange(len(lengths)), lengths)


def _rotate_z(v: Tensor, angle: Tensor) -> Tensor:
    """Rotate the xy part of (..., 3) or (..., 2) vectors by ``angle`` (broadcast over the leading dims)."""
    c, s = torch.cos(angle), torch.sin(angle)
    x, y = v[..., 0], v[..., 1]
    out = torch.stack((c * x - s * y, s * x + c * y), dim=-1)
    return torch.cat((out, v[..., 2:]), dim=-1) if v.shape[-1] == 3 else out


class MotionLibrary:
    """Clips on one skeleton, precomputed per frame and interpolated at arbitrary times (module doc).

    Args:
        clips: the clips (a list or a :class:`~mocap.motion.sources.MotionSet`), all for ``skeleton``.
            Duplicate names get a ``#2``, ``#3``... suffix so that :meth:`clip_index` is unambiguous.
        skeleton: the humanoid they drive.
        device, dtype: where and in which precision the packed tensors live.
        loop_heading: also accumulate the heading change per cycle of looping clips (default off).
        body_interp: ``"fk"`` (bodies by forward kinematics of the interpolated DoFs, the default)
            or ``"lerp"`` (interpolate the precomputed body frames; faster).
    """

    def __init__(
        self,
        clips: Sequence[Clip] | MotionSet,
        skeleton: Skeleton,
        device: torch.device | str = "cpu",
        dtype: torch.dtype = torch.float32,
        loop_heading: bool = False,
        body_interp: Literal["fk", "lerp"] = "fk",
        velocities: VelocityMode | None = None,
        velocity_sigma: float | None = None,
    ):
        if body_interp not in ("fk", "lerp"):
            raise ValueError(f"body_interp must be 'fk' or 'lerp', got {body_interp!r}")
        self.body_interp = body_interp
        # the motion source's choice (MotionSet) unless given here
        given = clips if isinstance(clips, MotionSet) else None
        self.velocities: VelocityMode = velocities or (given.velocities if given is not None else "forward")
        self.velocity_sigma = float(velocity_sigma or (given.velocity_sigma if given is not None else 2.0))
        if self.velocities not in ("forward", "central_smoothed"):
            raise ValueError(f"velocities must be 'forward' or 'central_smoothed', got {self.velocities!r}")
        clips = list(clips.clips if isinstance(clips, MotionSet) else clips)
        if not clips:
            raise MotionDataError("a motion library needs at least one clip")
        for clip in clips:
            check_clip_skeleton(clip, skeleton, clip.source or clip.name)
        self.skeleton = skeleton
        self.device = torch.device(device)
        self.dtype = dtype
        self.loop_heading = loop_heading
        self.clips = clips
        self.clip_names: list[str] = []
        seen: dict[str, int] = {}
        for clip in clips:
            seen[clip.name] = seen.get(clip.name, 0) + 1
            self.clip_names.append(clip.name if seen[clip.name] == 1 else f"{clip.name}#{seen[clip.name]}")
        self._index = {n: i for i, n in enumerate(self.clip_names)}
        self._build()
        self._grid: ControlGrid | None = None
        self.set_weights(None)

    # ------------------------------------------------------------------------------ precompute
    def _build(self) -> None:
        f64 = torch.float64
        sk = self.skeleton
        lengths = torch.tensor([c.num_frames for c in self.clips], dtype=torch.long)
        starts = torch.cumsum(lengths, 0) - lengths
        ends = starts + lengths - 1
        fps = torch.tensor([float(c.fps) for c in self.clips], dtype=f64)
        loops = torch.tensor([bool(c.loop) for c in self.clips])
        seg = _segment_ids(lengths)
        F = int(lengths.sum())
        first = torch.zeros(F, dtype=torch.bool)
        first[starts] = True
        last = torch.zeros(F, dtype=torch.bool)
        last[ends] = True

        root_pos = torch.from_numpy(np.concatenate([c.root_pos for c in self.clips])).to(f64)
        root_rot = torch.from_numpy(np.concatenate([c.root_rot for c in self.clips])).to(f64)
        joint_rot = torch.from_numpy(np.concatenate([c.joint_rot for c in self.clips])).to(f64)
        root_rot = self._sign_continuous(root_rot, first)

        # DoFs, unwrapped within each clip, each clip's mean brought into (-pi, pi].
        dof = dofs_from_local_rotations(sk, joint_rot)
        if dof.shape[-1]:
            step = torch.diff(dof, dim=0)
            wrapped = torch.remainder(step + math.pi, 2 * math.pi) - math.pi
            corr = torch.where(step.abs() < math.pi, torch.zeros_like(step), wrapped - step)
            corr = torch.cat((torch.zeros_like(dof[:1]), corr), 0)
            corr[first] = 0.0
            cs = torch.cumsum(corr, 0)
            cs = cs - cs[starts][seg]  # restart the accumulation at each clip's first frame
            dof = dof + cs
            mean = torch.zeros(len(self.clips), dof.shape[1], dtype=f64).index_add_(0, seg, dof) / lengths[:, None]
            dof = dof - (2 * math.pi * torch.round(mean / (2 * math.pi)))[seg]

        local_rot = self._sign_continuous(local_rotations_from_dofs(sk, dof), first)
        body_pos, body_rot = forward_kinematics(sk, root_pos, root_rot, local_rot)
        body_rot = self._sign_continuous(body_rot, first)

        # cycle transform of looping clips: heading change h and xy translation t (M(x) = Rz(h) x + t)
        p0, p1 = root_pos[starts, :2], root_pos[ends, :2]
        if self.loop_heading:
            dh = heading_angle(root_rot[ends]) - heading_angle(root_rot[starts])
            dh = torch.remainder(dh + math.pi, 2 * math.pi) - math.pi
        else:
            dh = torch.zeros(len(self.clips), dtype=f64)
        cyc_t = p1 - _rotate_z(p0, dh)
        dh = torch.where(loops, dh, torch.zeros_like(dh))
        cyc_t = torch.where(loops[:, None], cyc_t, torch.zeros_like(cyc_t))
        span = torch.tensor([h.range[1] - h.range[0] for h in sk.hinges], dtype=f64)
        wind = 2 * math.pi * torch.round((dof[ends] - dof[starts]) / (2 * math.pi))
        wind = torch.where(loops[:, None] & (span > 2 * math.pi + 1e-9), wind, torch.zeros_like(wind))

        # forward differences; a clip's last frame: next cycle's frame 0 (looping) or previous frame
        fr = fps[seg]
        idx = torch.arange(F)
        nxt = torch.where(last, idx, idx + 1)
        loop_f = loops[seg]
        fill_from = torch.where(loop_f, starts[seg], idx - 1)
        turn = dh[seg]

        def finish(v: Tensor, rotate: bool) -> Tensor:
            src = v[fill_from[last]]
            if rotate:
                src = _rotate_z(src, turn[last].reshape(-1, *([1] * (src.dim() - 2))))
            v[last] = src
            return v

        def lin(x: Tensor) -> Tensor:
            return (x[nxt] - x) * fr.reshape(-1, *([1] * (x.dim() - 1)))

        def ang(q: Tensor) -> Tensor:
            return angular_velocity(q, q[nxt], (1.0 / fr).reshape(-1, *([1] * (q.dim() - 2))))

        if self.velocities == "central_smoothed":  # PHC's code (mocap.motion.velocity)
            sigma = self.velocity_sigma
            body_lin_vel = gaussian_smooth(central_differences(body_pos, starts, lengths, fps), starts, lengths, sigma)
            body_ang_vel = gaussian_smooth(finish(ang(body_rot), True), starts, lengths, sigma)
            dof_vel = gaussian_smooth(central_differences(dof, starts, lengths, fps), starts, lengths, sigma)
        else:
            body_lin_vel = finish(lin(body_pos), True)
            body_ang_vel = finish(ang(body_rot), True)
            dof_vel = finish(lin(dof), False)

        dev, dt = self.device, self.dtype
        self._lengths = lengths.to(dev)
        self._starts = starts.to(dev)
        self._fps64 = fps.to(dev)
        self._dur64 = ((lengths - 1).to(f64) / fps).to(dev)
        self._loops = loops.to(dev)
        self._cyc_h = dh.to(dev)
        self._cyc_t = cyc_t.to(dev)
        self._cyc_dof = wind.to(dev)
        self._winds = bool(torch.any(wind != 0))
        #: packed per-frame tensors (all clips, frame order), (F, ...)
        self.root_pos = root_pos.to(dev, dt)
        self.root_rot = root_rot.to(dev, dt)
        self.dof_pos = dof.to(dev, dt)
        self.local_rot = local_rot.to(dev, dt)
        self.dof_vel = dof_vel.to(dev, dt)
        self.body_pos = body_pos.to(dev, dt)
        self.body_rot = body_rot.to(dev, dt)
        self.body_lin_vel = body_lin_vel.to(dev, dt)
        self.body_ang_vel = body_ang_vel.to(dev, dt)
        self.frame_clip = seg.to(dev)

    @staticmethod
    def _sign_continuous(q: Tensor, first: Tensor) -> Tensor:
        """Flip quaternion signs so that consecutive frames of a clip have a non-negative dot product."""
        d = (q[1:] * q[:-1]).sum(-1)
        flip = torch.cat((torch.ones_like(d[:1]), torch.where(d < 0, -1.0, 1.0).to(q.dtype)), 0)
        flip[first] = 1.0
        # running product of sign flips, restarted at each clip's first frame: a +-1 product is its own inverse
        cp = torch.cumprod(flip, 0)
        start_of = torch.cummax(torch.where(first, torch.arange(len(first)), 0), 0).values
        sign = cp * cp[start_of]
        return q * sign[..., None]

    # ------------------------------------------------------------------------------- metadata
    @property
    def num_clips(self) -> int:
        return len(self.clips)

    @property
    def num_frames(self) -> Tensor:
        """(C,) long, frames per clip."""
        return self._lengths

    @property
    def fps(self) -> Tensor:
        """(C,) frame rate per clip, Hz."""
        return self._fps64.to(self.dtype)

    @property
    def durations(self) -> Tensor:
        """(C,) first-to-last-frame time per clip, s (a looping clip's period), in the library's dtype."""
        return self._dur64.to(self.dtype)

    @property
    def durations64(self) -> Tensor:
        """(C,) :attr:`durations` in float64, unrounded (what start times on the control grid are
        compared with: a float32 duration can fall just below a grid time)."""
        return self._dur64.clone()

    @property
    def loops(self) -> Tensor:
        """(C,) bool, the clip wraps around."""
        return self._loops

    @property
    def cycle_offsets(self) -> Tensor:
        """(C, 2) horizontal root displacement added per completed cycle (zero for non-looping clips)."""
        return self._cyc_t.to(self.dtype)

    @property
    def cycle_dof_winding(self) -> Tensor:
        """(C, D) DoF advance per completed cycle: whole turns, nonzero only for looping clips and
        hinges whose range spans more than one turn (module docstring)."""
        return self._cyc_dof.to(self.dtype)

    @property
    def total_frames(self) -> int:
        return int(self.root_pos.shape[0])

    @property
    def weights(self) -> Tensor:
        """(C,) sampling probabilities of the clips (sum to 1)."""
        return self._weights

    def clip_index(self, name: str) -> int:
        """Index of the clip called ``name``; ``KeyError`` naming close matches otherwise."""
        try:
            return self._index[name]
        except KeyError:
            close = difflib.get_close_matches(name, self.clip_names, n=3)
            hint = f"; did you mean {', '.join(close)}?" if close else f"; clips: {', '.join(self.clip_names)}"
            raise KeyError(f"no clip {name!r} in the motion library{hint}") from None

    def info(self, clip: int | str) -> ClipInfo:
        """Summary of one clip (by index or name)."""
        i = self.clip_index(clip) if isinstance(clip, str) else int(clip)
        return ClipInfo.of(self.clips[i])

    def frame_index(self, clip_id: int, frame: int) -> int:
        """Row of frame ``frame`` of clip ``clip_id`` in the packed per-frame tensors."""
        return int(self._starts[clip_id]) + frame

    # ------------------------------------------------------------------------------- sampling
    def set_weights(self, weights: Sequence[float] | Tensor | None) -> None:
        """Per-clip sampling weights (non-negative, any scale); ``None`` means uniform over clips."""
        if weights is None:
            w = torch.ones(self.num_clips, dtype=torch.float64)
        else:
            w = torch.as_tensor(weights, dtype=torch.float64).flatten().cpu()
            if w.numel() != self.num_clips:
                raise ValueError(f"expected {self.num_clips} clip weights, got {w.numel()}")
            if not torch.all(torch.isfinite(w)) or torch.any(w < 0) or w.sum() <= 0:
                raise ValueError("clip weights must be finite, non-negative and not all zero")
        self._weights = (w / w.sum()).to(self.device)

    def sample(self, n: int, generator: torch.Generator | None = None, weights: Tensor | None = None) -> tuple[Tensor, Tensor]:
        """``n`` (clip id, time) pairs: clips drawn with :attr:`weights` (or the (C,) ``weights`` given), times uniform in ``[0, duration]``."""
        dev = generator.device if generator is not None else self.device
        ids = torch.multinomial((self._weights if weights is None else weights).to(dev), n, replacement=True, generator=generator)
        u = torch.rand(n, generator=generator, device=dev, dtype=torch.float64)
        times = u * self._dur64.to(dev)[ids]
        return ids.to(self.device), times.to(self.device, self.dtype)

    # -------------------------------------------------------------------------- interpolation
    def frames(self, clip_ids: Tensor, times: Tensor) -> MotionFrames:
        """Reference frames of clips ``clip_ids`` (N,) at ``times`` (N,) seconds (module doc).

        With a control-rate grid (:meth:`use_control_grid`), rows whose time is a grid time
        ``j dt`` (within 1e-9 s) inside the precomputed range are looked up; the others are computed."""
        dev = self.device
        c = torch.as_tensor(clip_ids, device=dev).long().reshape(-1)
        t = torch.as_tensor(times, device=dev).to(torch.float64).reshape(-1)
        if c.shape != t.shape:
            raise ValueError(f"clip_ids {tuple(c.shape)} and times {tuple(t.shape)} must have the same length")
        grid = self._grid
        if grid is None or c.numel() == 0:
            return self._frames_exact(c, t)
        j = torch.round(t * grid.inv_dt)
        rows = grid.offsets[c] + j.long()
        hit = (j >= 0) & (j < grid.lengths[c].to(j)) & ((t - j * grid.dt).abs() <= 1e-9)
        if bool(hit.all()):
            return grid.lookup(rows, c)
        out = grid.lookup(rows.where(hit, torch.zeros_like(rows)), c)
        miss = (~hit).nonzero().squeeze(-1)
        exact = self._frames_exact(c[miss], t[miss])
        for name in GRID_FIELDS:
            getattr(out, name)[miss] = getattr(exact, name)
        return out

    def frames_ahead(self, clip_ids: Tensor, times: Tensor, dt: float, steps: int) -> MotionFrames:
        """:meth:`frames` at ``times``, with ``ahead`` holding the frames ``dt``, ``2 dt``, ...
        later (``steps`` frames in all): the reference an imitator with
        ``reference_steps = steps`` observes. ``steps = 1``: plain :meth:`frames`."""
        if steps < 1:
            raise ValueError(f"steps must be >= 1, got {steps}")
        t = torch.as_tensor(times, device=self.device).to(torch.float64).reshape(-1)
        first = self.frames(clip_ids, t)
        if steps == 1:
            return first
        first.ahead = tuple(self.frames(clip_ids, t + k * float(dt)) for k in range(1, steps))
        return first

    def use_control_grid(self, dt: float | None, steps_past_end: int = 0, max_bytes: int = 512 * 2**20) -> bool:
        """Precompute every clip's frames at the grid times ``j dt`` (the control rate) so that
        :meth:`frames` at those times is a table lookup instead of interpolation and forward
        kinematics (:class:`ControlGrid`; the values are the computed ones at ``j dt``).

        Non-looping clips: ``j dt`` up to the clip's end, plus the end time itself (where later
        times clamp to). Looping clips: one period plus ``steps_past_end`` grid times (episodes that
        start late in a cycle and run on). ``dt=None`` removes the grid. Returns False (and keeps no
        grid) when the table would need more than ``max_bytes``: frames are then computed as before.
        """
        if dt is None:
            self._grid = None
            return False
        if self._grid is not None and self._grid.dt == float(dt) and self._grid.steps_past_end >= steps_past_end:
            return True
        self._grid = None
        grid = ControlGrid.build(self, float(dt), int(steps_past_end), max_bytes)
        self._grid = grid
        return grid is not None

    def _frames_exact(self, c: Tensor, t: Tensor) -> MotionFrames:
        dt = self.dtype
        dur, fps, loop = self._dur64[c], self._fps64[c], self._loops[c]
        k = torch.where(loop, torch.floor(t / dur), torch.zeros_like(t))
        tw = torch.where(loop, t - k * dur, t).clamp(min=0.0).minimum(dur)
        f = tw * fps
        i0 = torch.floor(f).long().clamp(min=0).minimum(self._lengths[c] - 2)
        alpha = (f - i0).clamp(0.0, 1.0).to(dt)
        g0 = self._starts[c] + i0
        g1 = g0 + 1

        def lerp(x: Tensor) -> Tensor:
            x0, x1 = x[g0], x[g1]
            return x0 + alpha.reshape(-1, *([1] * (x0.dim() - 1))) * (x1 - x0)

        dof_pos = lerp(self.dof_pos)
        dof_vel = lerp(self.dof_vel)
        body_lin_vel = lerp(self.body_lin_vel)
        body_ang_vel = lerp(self.body_ang_vel)
        if self.body_interp == "fk":
            root_pos = lerp(self.root_pos)
            root_rot = quat_slerp(self.root_rot[g0], self.root_rot[g1], alpha)
            local = quat_slerp(self.local_rot[g0], self.local_rot[g1], alpha[:, None])
            body_pos, body_rot = forward_kinematics(self.skeleton, root_pos, root_rot, local)
        else:
            body_pos = lerp(self.body_pos)
            body_rot = quat_slerp(self.body_rot[g0], self.body_rot[g1], alpha[:, None])

        if self._winds and bool(torch.any(k != 0)):
            dof_pos = dof_pos + (k[:, None] * self._cyc_dof[c]).to(dt)
        if bool(torch.any(k != 0)):
            body_pos, body_rot, body_lin_vel, body_ang_vel = self._apply_cycles(c, k, body_pos, body_rot, body_lin_vel, body_ang_vel)
        return MotionFrames(
            root_pos=body_pos[:, 0].clone(),
            root_rot=body_rot[:, 0].clone(),
            root_lin_vel=body_lin_vel[:, 0].clone(),
            root_ang_vel=body_ang_vel[:, 0].clone(),
            dof_pos=dof_pos,
            dof_vel=dof_vel,
            body_pos=body_pos,
            body_rot=body_rot,
            body_lin_vel=body_lin_vel,
            body_ang_vel=body_ang_vel,
            clip_ids=c,
            times=tw.to(dt),
        )

    def _apply_cycles(
        self, c: Tensor, k: Tensor, body_pos: Tensor, body_rot: Tensor, lin_vel: Tensor, ang_vel: Tensor
    ) -> tuple[Tensor, Tensor, Tensor, Tensor]:
        """Move cycle-0 frames to cycle ``k``: ``M^k(x) = Rz(k h) x + t_k``, ``t_k = sum_{j<k} Rz(j h) t``.

        ``t_k`` in closed form (complex geometric series):
        ``t_k = Rz((k - 1) h / 2) t sin(k h / 2) / sin(h / 2)``, which tends to ``k t`` as ``h -> 0``
        and also holds for negative ``k``.
        """
        dt = self.dtype
        h, t = self._cyc_h[c], self._cyc_t[c]
        if not self.loop_heading:
            shift = (k[:, None] * t).to(dt)
            body_pos = body_pos.clone()
            body_pos[..., :2] += shift[:, None, :]
            return body_pos, body_rot, lin_vel, ang_vel
        half = 0.5 * h
        s = torch.sin(half)
        small = s.abs() < 1e-9
        ratio = torch.where(small, k, torch.sin(k * half) / torch.where(small, torch.ones_like(s), s))
        t_k = ratio[:, None] * _rotate_z(t, (k - 1) * half)
        turn = (k * h).to(dt)[:, None]
        body_pos = _rotate_z(body_pos, turn)
        body_pos = torch.cat((body_pos[..., :2] + t_k.to(dt)[:, None, :], body_pos[..., 2:]), dim=-1)
        body_rot = quat_mul(yaw_quat(turn).expand_as(body_rot), body_rot)
        return body_pos, body_rot, _rotate_z(lin_vel, turn), _rotate_z(ang_vel, turn)


def grid_start_times(t0: Tensor, durations: Tensor, loops: Tensor, dt: float) -> Tensor:
    """Episode start times moved to the control grid: the grid time ``j dt`` at or before ``t0``
    (looping clips: inside the period ``[0, duration)``), so that every later step of the episode
    is a grid time (a :class:`ControlGrid` lookup)."""
    j = torch.floor(t0 / dt + 1e-9)
    j = torch.where(loops & (j * dt >= durations - 1e-9), (j - 1).clamp_min(0), j)
    return j * dt


#: MotionFrames fields a control grid stores (times: the wrapped clip time)
GRID_FIELDS: tuple[str, ...] = (*HUMANOID_FIELDS, "times")


@dataclass
class ControlGrid:
    """Every clip's reference frames at the grid times ``j dt``, packed into one (R, K) table.

    Row ``offsets[c] + j`` holds clip ``c`` at ``min(j dt, duration)`` (non-looping) or ``j dt``
    (looping, past the period with the cycle offsets applied), computed once by the library's own
    interpolation; a lookup is one ``index_select`` and the returned fields are views of its result
    (never of the table).
    """

    dt: float
    inv_dt: float
    steps_past_end: int
    offsets: Tensor  # (C,) long, first row of each clip
    lengths: Tensor  # (C,) long, grid times stored per clip
    table: Tensor  # (R, K)
    layout: tuple[tuple[str, int, tuple[int, ...]], ...]  # field, first column, trailing shape

    @classmethod
    def build(cls, lib: "MotionLibrary", dt: float, steps_past_end: int, max_bytes: int) -> "ControlGrid | None":
        if not dt > 0:
            raise ValueError(f"control grid dt must be > 0, got {dt}")
        dur = lib._dur64.cpu()
        last = torch.floor(dur / dt + 1e-9).long()  # last grid index inside [0, duration]
        loops = lib._loops.cpu()
        lengths = torch.where(loops, last + 1 + steps_past_end, last + 2)
        B, D = lib.skeleton.num_bodies, lib.skeleton.num_dofs
        widths: dict[str, tuple[int, ...]] = {"root_pos": (3,), "root_rot": (4,), "root_lin_vel": (3,), "root_ang_vel": (3,), "dof_pos": (D,), "dof_vel": (D,)}
        widths.update({"body_pos": (B, 3), "body_rot": (B, 4), "body_lin_vel": (B, 3), "body_ang_vel": (B, 3), "times": ()})
        layout, col = [], 0
        for name in GRID_FIELDS:
            layout.append((name, col, widths[name]))
            col += int(math.prod(widths[name]))
        R = int(lengths.sum())
        if R * col * torch.empty(0, dtype=lib.dtype).element_size() > max_bytes:
            return None
        clip = _segment_ids(lengths)
        offsets = torch.cumsum(lengths, 0) - lengths
        j = torch.arange(R) - offsets[clip]
        t = j.to(torch.float64) * dt
        t = torch.where(loops[clip], t, torch.minimum(t, dur[clip]))
        table = torch.empty(R, col, dtype=lib.dtype, device=lib.device)
        for a in range(0, R, 4096):
            b = min(R, a + 4096)
            f = lib._frames_exact(clip[a:b].to(lib.device), t[a:b].to(lib.device))
            table[a:b] = torch.cat([getattr(f, name).reshape(b - a, -1).to(lib.dtype) for name in GRID_FIELDS], dim=1)
        return cls(dt, 1.0 / dt, steps_past_end, offsets.to(lib.device), lengths.to(lib.device), table, tuple(layout))

    def lookup(self, rows: Tensor, clip_ids: Tensor) -> MotionFrames:
        x = self.table.index_select(0, rows)
        n = x.shape[0]
        out: dict[str, Any] = {name: x[:, c : c + int(math.prod(shape))].view(n, *shape) for name, c, shape in self.layout}
        return MotionFrames(**out, clip_ids=clip_ids)


__all__ = ["ClipInfo", "ControlGrid", "MotionLibrary", "grid_start_times"]
