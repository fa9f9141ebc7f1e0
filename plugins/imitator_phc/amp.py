"""The AMP discriminator reward of PHC+ (Peng et al. 2021, "AMP: Adversarial Motion Priors"; PHC
Eq. 1 and PULSE Eq. 5: ``r = 0.5 r^g + 0.5 r^amp + r^energy``), for any skeleton.

**AMP observation** (one frame, :class:`AMPObservation`; PHC code ``build_amp_observations_smpl``
reduced to what every skeleton has), all in the heading frame ``h`` of the root (yaw only), so a
global yaw plus planar translation leaves every feature unchanged::

    [ root height (1) | sixd(h^-1 q_root) (6) | h^-1 v_root (3) | h^-1 w_root (3)
      | joint features | DoF velocities (D) | h^-1 (p_k - p_root) for each key body k (3 K) ]

* joint features (``joints``): ``"rot6d"`` (default; PHC/AMP) = the 6-D of each actuated body's
  local rotation ``q_parent^-1 q_j`` (bodies whose joint has >= 1 hinge, in body order; a 1-hinge
  joint such as a knee still gets 6 numbers), or ``"dof"`` = the raw hinge angles (D), compact and
  exact for hinge-only skeletons (AMP's own humanoid uses angles for its 1-DoF knees and elbows;
  the 6-D form is continuous where angles wrap);
* 6-D convention ``sixd``: default ``"tan_norm"`` (rotated x and z axes), which is what both the
  AMP paper ("normal-tangent") and the PHC code use;
* key bodies: default the skeleton's ``end_effectors`` (PHC code: ankles and wrists; amp/ASE:
  hands and feet).

The discriminator input is ``history`` frames stacked newest first (paper/code: 10), flattened to
``(history * F,)``. Demo windows are built from the motion library at ``dt`` spacing:
``frames(c, t0 - k dt), k = 0 .. history - 1`` with ``t0`` drawn so that the window lies inside the
clip when the clip is long enough (the code's ``truncate_time``); looping clips may also reach into
the previous cycle.

**Losses** (switch ``loss``; :data:`LOSS_PRESETS` holds the constants):

* ``"lsgan"`` (AMP paper; PHC says "same loss formulation and gradient penalty as AMP"):
  ``E_demo (D - 1)^2 + E_pi (D + 1)^2 + w_gp / 2 E_demo ||grad_x D||^2``, ``w_gp = 10``; reward
  ``max(0, 1 - 0.25 (D - 1)^2)`` in [0, 1] (maximum 1 at D = 1);
* ``"bce"`` (official PHC/ASE code): ``0.5 (BCE(D_pi, 0) + BCE(D_demo, 1)) + w_gp E_demo ||grad_x D||^2``
  (``w_gp = 5``) ``+ 0.01 ||W_logit||^2 + 1e-4 sum ||W||^2``, all times ``disc_coef = 5``; reward
  ``scale * -log(max(1 - sigmoid(D), 1e-4))`` with ``scale = 2``, in ``[0, 2 * 9.21]``.

Note: the two gradient penalties have the same effective weight (10 / 2 = 5). ``disc_coef`` only
rescales the loss, which Adam (the code's optimizer) is nearly invariant to; the code applies it
because the discriminator shares the actor-critic's optimizer. The gradient is taken with respect
to the *normalized* discriminator input (as in the code).

**Samples.** Policy windows are collected by :meth:`DiscriminatorTrainer.observe_policy` during a
rollout. Each update step draws ``batch`` demo windows from a demo ring buffer that is first
refilled with ``batch`` fresh library windows (the code's demo buffer; filled lazily here instead of
200k windows at start-up), and ``batch`` policy windows: half from the last rollout and half from a
replay buffer of older rollouts once it holds samples (all from the rollout before). After the
update the rollout is stored into the replay buffer: every sample while the buffer has seen at most
``capacity`` samples, afterwards each sample with probability ``keep_prob`` (code: 200,000 and
0.01), overwriting the oldest.

All randomness (demo draws, batch indices, replay keeps) comes from the trainer's own
``torch.Generator``; :meth:`DiscriminatorTrainer.state_dict` saves it with the network, the
optimizer, the normalizer and every buffer, so a resumed run continues bit for bit.
"""

from __future__ import annotations

import copy
import math
from collections.abc import Callable, Sequence
from dataclasses import dataclass, replace
from typing import Any, Literal

import torch
import torch.nn.functional as F
from mocap.motion.library import MotionLibrary
from mocap.observations import SixD, rotation_sixd
from mocap.rl.normalizer import RunningNormalizer
from mocap.rotations import heading_quat_inv, quat_apply, quat_conjugate, quat_mul
from mocap.skeleton import Skeleton
from mocap.state import HumanoidState
from torch import Tensor, nn

AMPLoss = Literal["lsgan", "bce"]
JointFeatures = Literal["rot6d", "dof"]
#: the smallest ``1 - sigmoid(D)`` in the BCE reward (code: 1e-4), so the reward is <= -log(1e-4) * scale
BCE_REWARD_FLOOR = 1e-4


# ------------------------------------------------------------------------------- observation
class AMPObservation:
    """Per-frame AMP features of a :class:`HumanoidState` (module doc).

    Args:
        skeleton: the humanoid.
        joints: ``"rot6d"`` (local rotations as 6-D) or ``"dof"`` (hinge angles).
        sixd: 6-D convention (``"tan_norm"`` as AMP and the PHC code).
        key_bodies: body names; None = ``skeleton.end_effectors``.
        exclude: bodies whose joint features and DoF velocities are left out (PHC's code on smpl:
            the hands and toes, 19 of 23 joints: 196 features per frame with its 4 key bodies).
    """

    def __init__(
        self,
        skeleton: Skeleton,
        joints: JointFeatures = "rot6d",
        sixd: SixD = "tan_norm",
        key_bodies: Sequence[str] | None = None,
        exclude: Sequence[str] = (),
    ):
        if joints not in ("rot6d", "dof"):
            raise ValueError(f"unknown AMP joint features {joints!r}; choose 'rot6d' or 'dof'")
        self.skeleton = skeleton
        self.joints = joints
        self.sixd = sixd
        names = tuple(skeleton.end_effectors if key_bodies is None else key_bodies)
        self.key_bodies = names
        self.key_ids = torch.tensor([skeleton.body_index(n) for n in names], dtype=torch.long)
        skipped = {skeleton.body_index(n) for n in exclude}  # KeyError naming the skeleton's bodies
        self.joint_ids = torch.tensor(
            [i for i, b in enumerate(skeleton.bodies) if i > 0 and len(b.joint.hinges) > 0 and i not in skipped],
            dtype=torch.long,
        )
        self.parent_ids = torch.tensor([skeleton.bodies[int(i)].parent for i in self.joint_ids], dtype=torch.long)
        slices = skeleton.dof_slices
        self.dof_ids = torch.tensor([d for i, sl in enumerate(slices) if i not in skipped for d in range(sl.start, sl.stop)], dtype=torch.long)
        D = int(self.dof_ids.numel())
        joint_dim = 6 * int(self.joint_ids.numel()) if joints == "rot6d" else D
        self.dim = 1 + 6 + 3 + 3 + joint_dim + D + 3 * len(names)

    def __call__(self, state: HumanoidState) -> Tensor:
        """(N, F) features; non-finite entries (an unstable simulation) become 0."""
        N = state.root_pos.shape[0]
        h_inv = heading_quat_inv(state.root_rot)  # (N, 4)
        root_h = state.root_pos[:, 2:3]
        root_rot = rotation_sixd(quat_mul(h_inv, state.root_rot), self.sixd)
        lin = quat_apply(h_inv, state.root_lin_vel)
        ang = quat_apply(h_inv, state.root_ang_vel)
        if self.joints == "rot6d":
            dev = state.body_rot.device
            child = state.body_rot[:, self.joint_ids.to(dev)]
            parent = state.body_rot[:, self.parent_ids.to(dev)]
            joint = rotation_sixd(quat_mul(quat_conjugate(parent), child), self.sixd).reshape(N, -1)
        else:
            joint = state.dof_pos[:, self.dof_ids.to(state.dof_pos.device)]
        dof_vel = state.dof_vel[:, self.dof_ids.to(state.dof_vel.device)]
        keys = state.body_pos[:, self.key_ids.to(state.body_pos.device)] - state.root_pos[:, None, :]
        keys = quat_apply(h_inv[:, None, :].expand(-1, keys.shape[1], -1), keys).reshape(N, -1)
        out = torch.cat((root_h, root_rot, lin, ang, joint, dof_vel, keys), dim=-1).float()
        return torch.nan_to_num(out, nan=0.0, posinf=0.0, neginf=0.0)


def demo_windows(
    library: MotionLibrary,
    obs: AMPObservation,
    n: int,
    history: int,
    dt: float,
    generator: torch.Generator | None = None,
) -> Tensor:
    """``n`` demo windows (n, history * F), newest frame first: clips drawn with the library's
    weights, end time ``t0`` uniform in ``[(history - 1) dt, duration]`` (just ``duration`` when the
    clip is shorter; earlier frames then clamp to the clip's start), frames ``t0 - k dt``."""
    clips, _ = library.sample(n, generator=generator)
    dev = generator.device if generator is not None else library.device
    u = torch.rand(n, generator=generator, device=dev, dtype=torch.float64).to(library.device)
    dur = library.durations.to(library.device, torch.float64)[clips]
    span = (history - 1) * dt
    t0 = torch.minimum(dur, span + u * (dur - span).clamp_min(0.0))
    return window_frames(library, obs, clips, t0, history, dt)


def window_frames(
    library: MotionLibrary,
    obs: AMPObservation,
    clips: Tensor,
    t_end: Tensor,
    history: int,
    dt: float,
    first: int = 0,
) -> Tensor:
    """(n, history - first, F) library features at ``t_end - k dt`` for ``k = first .. history - 1``
    (times of non-looping clips clamp at 0, so a window reaching before the start repeats frame 0)."""
    n = int(clips.numel())
    k = torch.arange(first, history, dtype=torch.float64, device=library.device)
    times = t_end.to(library.device, torch.float64)[:, None] - k[None, :] * dt
    loops = library.loops.to(library.device)[clips]
    times = torch.where(loops[:, None], times, times.clamp_min(0.0))
    frames = library.frames(clips.repeat_interleave(history - first), times.reshape(-1))
    return obs(frames).reshape(n, history - first, obs.dim)


class AMPHistory:
    """Rolling (N, history, F) AMP frames, index 0 the newest."""

    def __init__(self, num_envs: int, history: int, dim: int):
        self.buf = torch.zeros(num_envs, history, dim)

    @property
    def history(self) -> int:
        return int(self.buf.shape[1])

    def push(self, frame: Tensor) -> None:
        """Shift every env's window by one frame and put ``frame`` (N, F) first."""
        self.buf = torch.cat((frame.to(self.buf)[:, None], self.buf[:, :-1]), dim=1)

    def fill(self, ids: Tensor, window: Tensor) -> None:
        """Overwrite envs ``ids`` with ``window`` (n, history, F)."""
        self.buf[ids.to(self.buf.device)] = window.to(self.buf)

    def flat(self) -> Tensor:
        """(N, history * F) discriminator input."""
        return self.buf.reshape(self.buf.shape[0], -1).clone()


# ----------------------------------------------------------------------- losses and rewards
@dataclass(frozen=True)
class AMPLossConfig:
    """Discriminator objective constants (module doc)."""

    loss: AMPLoss = "lsgan"
    grad_penalty: float = 10.0  # lsgan: w_gp (applied as w_gp / 2); bce: applied as is
    logit_reg: float = 0.0
    weight_decay: float = 0.0
    coef: float = 1.0
    reward_scale: float = 1.0


#: ``lsgan`` = AMP paper (PHC paper), ``bce`` = official PHC/ASE code
LOSS_PRESETS: dict[str, AMPLossConfig] = {
    "lsgan": AMPLossConfig(
        "lsgan",
        grad_penalty=10.0,
        logit_reg=0.0,
        weight_decay=0.0,
        coef=1.0,
        reward_scale=1.0,
    ),
    "bce": AMPLossConfig(
        "bce",
        grad_penalty=5.0,
        logit_reg=0.01,
        weight_decay=1e-4,
        coef=5.0,
        reward_scale=2.0,
    ),
}


def loss_config(loss: AMPLoss, grad_penalty: float | None = None, reward_scale: float | None = None) -> AMPLossConfig:
    if loss not in LOSS_PRESETS:
        raise ValueError(f"unknown AMP loss {loss!r}; choose 'lsgan' (paper) or 'bce' (code)")
    cfg = LOSS_PRESETS[loss]
    if grad_penalty is not None:
        cfg = replace(cfg, grad_penalty=float(grad_penalty))
    if reward_scale is not None:
        cfg = replace(cfg, reward_scale=float(reward_scale))
    return cfg


def lsgan_loss(d_demo: Tensor, d_policy: Tensor) -> Tensor:
    """``E (D_demo - 1)^2 + E (D_policy + 1)^2``."""
    return (d_demo - 1.0).square().mean() + (d_policy + 1.0).square().mean()


def bce_loss(d_demo: Tensor, d_policy: Tensor) -> Tensor:
    """``0.5 (BCE(D_policy, 0) + BCE(D_demo, 1))`` on logits."""
    return 0.5 * (
        F.binary_cross_entropy_with_logits(d_policy, torch.zeros_like(d_policy)) + F.binary_cross_entropy_with_logits(d_demo, torch.ones_like(d_demo))
    )


def lsgan_reward(d: Tensor, scale: float = 1.0) -> Tensor:
    """``scale * max(0, 1 - 0.25 (D - 1)^2)``: in [0, scale], maximal at D = 1."""
    return scale * (1.0 - 0.25 * (d - 1.0).square()).clamp_min(0.0)


def bce_reward(d: Tensor, scale: float = 2.0) -> Tensor:
    """``scale * -log(max(1 - sigmoid(D), 1e-4))``: non-decreasing in D, in ``[0, -log(1e-4) scale]``."""
    return -scale * torch.log(torch.clamp(1.0 - torch.sigmoid(d), min=BCE_REWARD_FLOOR))


def amp_reward(d: Tensor, cfg: AMPLossConfig) -> Tensor:
    return lsgan_reward(d, cfg.reward_scale) if cfg.loss == "lsgan" else bce_reward(d, cfg.reward_scale)


def gradient_penalty(disc: Callable[[Tensor], Tensor], x: Tensor) -> Tensor:
    """``E ||grad_x D(x)||^2`` (>= 0; 0 for a discriminator that is constant in x). Differentiable."""
    x = x.detach().requires_grad_(True)
    out = disc(x)
    if not out.requires_grad:  # D does not depend on x at all
        return out.new_zeros(())
    (grad,) = torch.autograd.grad(out.sum(), x, create_graph=True, allow_unused=True)
    if grad is None:  # D does not depend on x
        return out.new_zeros(())
    return grad.square().sum(-1).mean()


# ------------------------------------------------------------------------------ discriminator
class Discriminator(nn.Module):
    """``D(x) = logit(MLP(normalize(x)))``: ReLU MLP ``hidden`` (paper/code [1024, 512]) and a linear
    logit; inputs normalized by running mean/std (clamped to +-5)."""

    def __init__(self, input_dim: int, hidden: Sequence[int] = (1024, 512)):
        super().__init__()
        self.input_dim = int(input_dim)
        self.norm = RunningNormalizer(self.input_dim, clip=5.0, eps=1e-5)
        layers: list[nn.Module] = []
        width = self.input_dim
        for h in hidden:
            layers += [nn.Linear(width, int(h)), nn.ReLU()]
            width = int(h)
        self.trunk = nn.Sequential(*layers)
        self.logit = nn.Linear(width, 1)
        nn.init.uniform_(self.logit.weight, -1e-2, 1e-2)  # start near D = 0 for every input
        nn.init.zeros_(self.logit.bias)

    def logits_normalized(self, z: Tensor) -> Tensor:
        """(n,) logits of already-normalized inputs (n, input_dim)."""
        return self.logit(self.trunk(z)).squeeze(-1)

    def forward(self, x: Tensor) -> Tensor:
        return self.logits_normalized(self.norm.normalize(x.float()))

    def weights(self) -> list[Tensor]:
        return [m.weight for m in self.modules() if isinstance(m, nn.Linear)]


def discriminator_loss(disc: Discriminator, demo: Tensor, policy: Tensor, cfg: AMPLossConfig) -> tuple[Tensor, dict[str, float]]:
    """The objective of ``cfg.loss`` on raw inputs (module doc) and scalar statistics."""
    z_demo = disc.norm.normalize(demo.float())
    z_pol = disc.norm.normalize(policy.float())
    z_demo = z_demo.detach().requires_grad_(True)
    d_demo = disc.logits_normalized(z_demo)
    d_pol = disc.logits_normalized(z_pol)
    (grad,) = torch.autograd.grad(d_demo.sum(), z_demo, create_graph=True)
    gp = grad.square().sum(-1).mean()
    if cfg.loss == "lsgan":
        core = lsgan_loss(d_demo, d_pol)
        total = core + 0.5 * cfg.grad_penalty * gp
    else:
        core = bce_loss(d_demo, d_pol)
        total = core + cfg.grad_penalty * gp
    acc = 0.5 * ((d_demo > 0).float().mean() + (d_pol < 0).float().mean())
    if cfg.logit_reg:
        total = total + cfg.logit_reg * disc.logit.weight.square().sum()
    if cfg.weight_decay:
        total = total + cfg.weight_decay * sum(w.square().sum() for w in disc.weights())
    total = cfg.coef * total
    stats = {
        "loss": float(total.detach()),
        "objective": float(core.detach()),
        "grad_penalty": float(gp.detach()),
        "demo_logit": float(d_demo.detach().mean()),
        "policy_logit": float(d_pol.detach().mean()),
        "accuracy": float(acc),
    }
    return total, stats


# ------------------------------------------------------------------------------------ buffers
class ReplayBuffer:
    """Ring buffer of (dim,) samples with the code's keep rule (module doc).

    ``keep_prob = 1`` makes it a plain ring buffer (the demo buffer). Storage is allocated on the
    first store (``torch.empty``: memory is only touched as it fills).
    """

    def __init__(self, capacity: int, dim: int, keep_prob: float = 1.0):
        if capacity < 1:
            raise ValueError("a replay buffer needs capacity >= 1")
        self.capacity = int(capacity)
        self.dim = int(dim)
        self.keep_prob = float(keep_prob)
        self.data: Tensor | None = None
        self.size = 0
        self.head = 0
        self.total = 0  # samples written so far (the keep rule starts once it exceeds the capacity)

    def __len__(self) -> int:
        return self.size

    def store(self, x: Tensor, generator: torch.Generator | None = None) -> int:
        """Offer samples ``x`` (n, dim); returns how many were written."""
        x = x.detach().float().cpu().reshape(-1, self.dim)
        if self.total > self.capacity and self.keep_prob < 1.0:
            keep = torch.rand(x.shape[0], generator=generator) < self.keep_prob
            x = x[keep]
        if x.shape[0] > self.capacity:
            x = x[torch.randperm(x.shape[0], generator=generator)[: self.capacity]]
        n = int(x.shape[0])
        self.total += n
        if n == 0:
            return 0
        if self.data is None:
            self.data = torch.empty(self.capacity, self.dim)
        idx = (self.head + torch.arange(n)) % self.capacity
        self.data[idx] = x
        self.head = (self.head + n) % self.capacity
        self.size = min(self.capacity, self.size + n)
        return n

    def sample(self, n: int, generator: torch.Generator | None = None) -> Tensor:
        if self.size == 0 or self.data is None:
            raise RuntimeError("sampling an empty replay buffer")
        idx = torch.randint(0, self.size, (n,), generator=generator)
        return self.data[idx].clone()

    def state_dict(self) -> dict[str, Any]:
        data = torch.zeros(0, self.dim) if self.data is None else self.data[: self.size].clone()
        return {
            "capacity": self.capacity,
            "keep_prob": self.keep_prob,
            "data": data,
            "size": self.size,
            "head": self.head,
            "total": self.total,
        }

    def load_state_dict(self, state: dict[str, Any]) -> None:
        if int(state["capacity"]) != self.capacity or tuple(state["data"].shape[1:]) != (self.dim,):
            raise ValueError("replay buffer state of a different capacity or sample size")
        self.size, self.head, self.total = (
            int(state["size"]),
            int(state["head"]),
            int(state["total"]),
        )
        self.data = None
        if self.size:
            self.data = torch.empty(self.capacity, self.dim)
            self.data[: self.size] = state["data"]


# -------------------------------------------------------------------------------------- trainer
DemoFn = Callable[[int, torch.Generator], Tensor]


class DiscriminatorTrainer:
    """Trains the AMP discriminator and turns it into a reward (module doc).

    Args:
        input_dim: ``history * F``.
        demo_fn: ``(n, generator) -> (n, input_dim)`` fresh demo windows (:func:`demo_windows`).
        cfg: the loss (:func:`loss_config`).
        hidden: MLP widths.
        lr: Adam learning rate.
        replay_size, replay_keep_prob, demo_buffer_size: buffers.
        seed: seeds the network initialization (without touching the global RNG) and the
            trainer's generator.
    """

    def __init__(
        self,
        input_dim: int,
        demo_fn: DemoFn,
        cfg: AMPLossConfig | None = None,
        hidden: Sequence[int] = (1024, 512),
        lr: float = 2e-5,
        replay_size: int = 200_000,
        replay_keep_prob: float = 0.01,
        demo_buffer_size: int = 200_000,
        seed: int = 0,
    ):
        self.cfg = cfg or LOSS_PRESETS["lsgan"]
        self.input_dim = int(input_dim)
        self.demo_fn = demo_fn
        with torch.random.fork_rng(devices=[]):
            torch.manual_seed(int(seed))
            self.disc = Discriminator(self.input_dim, hidden)
        self.optimizer = torch.optim.Adam(self.disc.parameters(), lr=lr)
        self.gen = torch.Generator().manual_seed(int(seed) + 1)
        self.replay = ReplayBuffer(replay_size, self.input_dim, replay_keep_prob)
        self.demo = ReplayBuffer(demo_buffer_size, self.input_dim, 1.0)
        self._recent: list[Tensor] = []
        self.updates = 0

    def observe_policy(self, amp_obs: Tensor) -> None:
        """Collect policy windows (n, input_dim) of the current rollout."""
        self._recent.append(amp_obs.detach().float().cpu().reshape(-1, self.input_dim).clone())

    @property
    def num_recent(self) -> int:
        return sum(int(x.shape[0]) for x in self._recent)

    def reward(self, amp_obs: Tensor) -> Tensor:
        """(n,) AMP reward of windows (n, input_dim) under the current discriminator (no update)."""
        with torch.no_grad():
            d = self.disc(amp_obs.detach().float().cpu().reshape(-1, self.input_dim))
            return amp_reward(d, self.cfg).to(amp_obs.device)

    def logits(self, amp_obs: Tensor) -> Tensor:
        with torch.no_grad():
            return self.disc(amp_obs.detach().float().cpu().reshape(-1, self.input_dim))

    def update(self, num_steps: int, batch: int) -> dict[str, float]:
        """``num_steps`` optimizer steps on ``batch`` demo and ``batch`` policy windows each; then the
        rollout's windows move to the replay buffer. Returns mean statistics ({} without samples)."""
        recent = torch.cat(self._recent) if self._recent else torch.zeros(0, self.input_dim)
        self._recent = []
        if recent.shape[0] == 0 and len(self.replay) == 0:
            return {}
        sums: dict[str, float] = {}
        g = self.gen
        for _ in range(int(num_steps)):
            self.demo.store(self.demo_fn(batch, g), g)
            demo = self.demo.sample(batch, g)
            if recent.shape[0] and len(self.replay):
                half = batch // 2
                pol = torch.cat(
                    (
                        recent[torch.randint(0, recent.shape[0], (half,), generator=g)],
                        self.replay.sample(batch - half, g),
                    )
                )
            elif recent.shape[0]:
                pol = recent[torch.randint(0, recent.shape[0], (batch,), generator=g)]
            else:
                pol = self.replay.sample(batch, g)
            self.disc.train()
            self.disc.norm.update(torch.cat((demo, pol)))
            loss, stats = discriminator_loss(self.disc, demo, pol, self.cfg)
            self.optimizer.zero_grad(set_to_none=True)
            loss.backward()
            self.optimizer.step()
            self.disc.eval()
            for k, v in stats.items():
                sums[k] = sums.get(k, 0.0) + v
            self.updates += 1
        if recent.shape[0]:
            self.replay.store(recent, g)
        out = {k: v / max(int(num_steps), 1) for k, v in sums.items()}
        out["replay_size"] = float(len(self.replay))
        return out

    def state_dict(self) -> dict[str, Any]:
        return {
            "disc": copy.deepcopy(self.disc.state_dict()),
            "optimizer": copy.deepcopy(self.optimizer.state_dict()),
            "generator": self.gen.get_state().clone(),
            "replay": self.replay.state_dict(),
            "demo": self.demo.state_dict(),
            "recent": [x.clone() for x in self._recent],
            "updates": self.updates,
            "loss": self.cfg.loss,
        }

    def carry_from(self, state: dict[str, Any]) -> None:
        """Continue another phase's discriminator (PHC Sec. 3.2, Alg. 1: the discriminator is not re-initialized
        between primitives but fine-tuned on): its network, optimizer moments and update count from
        ``state`` (a :meth:`state_dict`); this trainer keeps its own demo buffer (the clips of its own
        phase), replay buffer and generator."""
        if state.get("loss", self.cfg.loss) != self.cfg.loss:
            raise ValueError(f"discriminator state was trained with loss {state['loss']!r}, this trainer uses {self.cfg.loss!r}")
        self.disc.load_state_dict(state["disc"])
        self.optimizer.load_state_dict(copy.deepcopy(state["optimizer"]))
        self.updates = int(state["updates"])
        self.disc.eval()

    def load_state_dict(self, state: dict[str, Any]) -> None:
        if state.get("loss", self.cfg.loss) != self.cfg.loss:
            raise ValueError(f"discriminator state was trained with loss {state['loss']!r}, this trainer uses {self.cfg.loss!r}")
        self.disc.load_state_dict(state["disc"])
        self.optimizer.load_state_dict(copy.deepcopy(state["optimizer"]))
        self.gen.set_state(state["generator"].clone())
        self.replay.load_state_dict(state["replay"])
        self.demo.load_state_dict(state["demo"])
        self._recent = [x.clone() for x in state["recent"]]
        self.updates = int(state["updates"])
        self.disc.eval()


def max_bce_reward(scale: float = 2.0) -> float:
    """The BCE reward's upper bound ``-log(1e-4) * scale``."""
    return -math.log(BCE_REWARD_FLOOR) * scale


__all__ = [
    "BCE_REWARD_FLOOR",
    "LOSS_PRESETS",
    "AMPHistory",
    "AMPLossConfig",
    "AMPObservation",
    "Discriminator",
    "DiscriminatorTrainer",
    "ReplayBuffer",
    "amp_reward",
    "bce_loss",
    "bce_reward",
    "demo_windows",
    "discriminator_loss",
    "gradient_penalty",
    "loss_config",
    "lsgan_loss",
    "lsgan_reward",
    "max_bce_reward",
    "window_frames",
]
