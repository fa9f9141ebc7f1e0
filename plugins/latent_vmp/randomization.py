"""VMP's domain randomization (paper section 4.9) for the tracking env: body masses, ground friction,
random pushes. Off by default (``VmpTrackerParams.randomization: null``).

Tags: [P] paper, [T1] Table 1, [T1?] Table 1 but illegible, [X] our choice (the paper gives no value).

* **Masses** (at every reset of an env): each body's mass *and* inertia are scaled by its own factor
  ``U[1 - eps_m, 1 + eps_m]`` (uniform density change; [P] "rigid-body mass", eps_m = 10 % [T1 robot;
  the humanoid's value is illegible, T1?]); MuJoCo's derived constants are recomputed
  (``mj_setConst``).
* **Ground friction** (at every reset): the ground's sliding friction ``U[lo, hi]`` ([P] randomized,
  range [X] 0.5-1.25). The ground geom gets contact priority 1 so that its coefficient, not the
  maximum with the body geom's, is the contact's.
* **Pushes** ([P] random forces and torques on the root, head, hands and feet; magnitudes and
  timing [X]): per env, the next push comes after ``U[interval]`` seconds; it picks one of the push
  bodies, a force of uniform random direction and magnitude ``U[0, force_max_mg] * m_total * g`` and a
  torque of random direction and magnitude ``U[0, torque_max]``, held (MuJoCo ``xfrc_applied``, world
  frame, at the body's centre of mass) for ``U[duration]`` seconds (at least one control step).

The simulator must offer ``env_models()`` and ``set_external_wrench`` (the ``mocap.interfaces.PerEnvModels``
and ``ExternalWrench`` capabilities; the ``mujoco`` simulator does).
Randomized physical parameters are redrawn on reset, so an exact resume re-applies them from
:meth:`DomainRandomizer.state_dict`.
"""

from __future__ import annotations

import math
from typing import Any

import numpy as np
import torch
from torch import Tensor

from mocap.interfaces import ExternalWrench, PerEnvModels
from mocap_vmp.tracking_params import DomainRandomizationParams, Range

__all__ = ["DomainRandomizationParams", "DomainRandomizer", "default_push_bodies"]


def default_push_bodies(skeleton: Any) -> list[str]:
    names = [skeleton.bodies[0].name]
    names += [b.name for b in skeleton.bodies[1:] if any(k in b.name for k in ("head", "hand", "foot"))]
    return names


class DomainRandomizer:
    """Applies :class:`DomainRandomizationParams` to a simulator's N envs (module docstring)."""

    def __init__(self, params: DomainRandomizationParams, sim: Any, generator: torch.Generator):
        import mujoco

        offered: object = sim  # checked as declared capabilities; ``sim`` stays the MuJoCo simulator it reads below
        if not isinstance(offered, ExternalWrench) or not isinstance(offered, PerEnvModels):
            raise TypeError(
                "domain randomization needs a simulator with external wrenches and per-env models "
                f"(mocap.interfaces.ExternalWrench and PerEnvModels: the mujoco simulator); {type(sim).__name__} has not both"
            )
        self.params = p = params
        self.sim = sim
        self.gen = generator
        self.N = N = int(sim.num_envs)
        self.dt = float(sim.dt)
        sk = sim.skeleton
        self.B = sk.num_bodies
        base = sim.model
        self._mj_body = np.asarray(sim.index.body_ids, dtype=np.int64)
        self._base_mass = base.body_mass[self._mj_body].copy()
        self._base_inertia = base.body_inertia[self._mj_body].copy()
        self._floor = int(sim.index.floor_geom)
        self._base_friction = base.geom_friction[self._floor].copy() if self._floor >= 0 else None
        self.total_mass = float(self._base_mass.sum())
        names = p.push_bodies if p.push_bodies is not None else default_push_bodies(sk)
        self.push_bodies = torch.tensor([sk.body_index(n) for n in names], dtype=torch.long)
        self.mass_scale = torch.ones(N, self.B, dtype=torch.float64)
        self.friction = torch.full((N,), float(self._base_friction[0]) if self._base_friction is not None else math.nan, dtype=torch.float64)
        self.push_countdown = torch.zeros(N, dtype=torch.long)  # control steps until the next push
        self.push_left = torch.zeros(N, dtype=torch.long)  # control steps the current push still lasts
        self.wrench = torch.zeros(N, self.B, 6, dtype=torch.float64)
        self._models = sim.env_models() if (p.mass_pct or p.ground_friction is not None) else None
        self._scratch = mujoco.MjData(base) if self._models is not None else None

    # ---------------------------------------------------------------------------- sampling
    def _uniform(self, shape: tuple[int, ...], lo: float, hi: float) -> Tensor:
        return lo + (hi - lo) * torch.rand(shape, generator=self.gen, dtype=torch.float64)

    def _steps(self, r: Range, n: int) -> Tensor:
        return torch.clamp(torch.round(self._uniform((n,), r[0], r[1]) / self.dt), min=1).long()

    def _random_dirs(self, n: int) -> Tensor:
        v = torch.randn(n, 3, generator=self.gen, dtype=torch.float64)
        return v / v.norm(dim=-1, keepdim=True).clamp_min(1e-12)

    # ------------------------------------------------------------------------------ resets
    def on_reset(self, ids: Tensor) -> None:
        """New masses / friction for envs ``ids`` (before the simulator's reset), restart their push timer."""
        ids = torch.as_tensor(ids).long().reshape(-1).cpu()
        n = int(ids.numel())
        if n == 0:
            return
        p = self.params
        if p.mass_pct:
            e = p.mass_pct / 100.0
            self.mass_scale[ids] = self._uniform((n, self.B), 1.0 - e, 1.0 + e)
        if p.ground_friction is not None and self._floor >= 0:
            self.friction[ids] = self._uniform((n,), *p.ground_friction)
        self._apply_models(ids)
        if p.push_interval_s is not None:
            self.push_countdown[ids] = self._steps(p.push_interval_s, n)
        self.push_left[ids] = 0
        self.wrench[ids] = 0.0  # the simulator clears its wrenches of reset envs

    def _apply_models(self, ids: Tensor) -> None:
        import mujoco

        if self._models is None:
            return
        p = self.params
        for i in ids.tolist():
            m = self._models[i]
            if p.mass_pct:
                s = self.mass_scale[i].numpy()
                m.body_mass[self._mj_body] = self._base_mass * s
                m.body_inertia[self._mj_body] = self._base_inertia * s[:, None]
                mujoco.mj_setConst(m, self._scratch)
            if p.ground_friction is not None and self._floor >= 0:
                m.geom_friction[self._floor, 0] = float(self.friction[i])
                m.geom_priority[self._floor] = 1

    # ------------------------------------------------------------------------------ pushes
    def before_step(self) -> None:
        """Advance the push timers by one control step: start new pushes, end finished ones."""
        p = self.params
        if p.push_interval_s is None:
            return
        ending = self.push_left == 1
        self.push_left = (self.push_left - 1).clamp_min(0)
        self.push_countdown = (self.push_countdown - 1).clamp_min(0)
        start = (self.push_countdown == 0) & (self.push_left == 0)
        changed = ending | start
        if not bool(changed.any()):
            return
        self.wrench[ending] = 0.0
        ids = start.nonzero().squeeze(-1)
        n = int(ids.numel())
        if n:
            body = self.push_bodies[torch.randint(len(self.push_bodies), (n,), generator=self.gen)]
            f = self._random_dirs(n) * self._uniform((n, 1), 0.0, p.push_force_max_mg * self.total_mass * 9.81)
            t = self._random_dirs(n) * self._uniform((n, 1), 0.0, p.push_torque_max)
            w = torch.zeros(n, self.B, 6, dtype=torch.float64)
            w[torch.arange(n), body] = torch.cat((f, t), -1)
            self.wrench[ids] = w
            self.push_left[ids] = self._steps(p.push_duration_s, n)
            self.push_countdown[ids] = self._steps(p.push_interval_s, n) + self.push_left[ids]
        rows = changed.nonzero().squeeze(-1)
        self.sim.set_external_wrench(rows, self.wrench[rows])

    # ------------------------------------------------------------------------------ resume
    def state_dict(self) -> dict[str, Tensor]:
        return {k: getattr(self, k).clone() for k in ("mass_scale", "friction", "push_countdown", "push_left", "wrench")}

    def load_state_dict(self, state: dict[str, Tensor]) -> None:
        for k, v in state.items():
            setattr(self, k, v.clone())
        all_ids = torch.arange(self.N)
        self._apply_models(all_ids)
        if self.params.push_interval_s is not None:
            self.sim.set_external_wrench(all_ids, self.wrench)
