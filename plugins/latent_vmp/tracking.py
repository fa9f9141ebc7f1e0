"""VMP stage II: the latent-conditioned tracking policy's environment, reward, termination and imitator.

Tags: [P] the paper (digest vmp.md), [T1] its Table 1, [D] our decision where the paper is silent
(digest section 9.5), [C] none (the paper has no public code).

**Time convention** [D] (the one of the project's imitation protocol, :mod:`mocap.evaluation`): the
observation built before a control step holds the reference frame ``m_t`` *of the time that step
reaches*; the reward and the termination compare the state after the step with that same frame.
The reference advances by one control step ``dt`` per step (at 30 Hz clips and the default 1/30 s
control step this is exactly one clip frame per step, the paper's "shift by one frame").

**Observation** (flat, in this order; ``B`` bodies, ``A`` actions, ``F`` = stage-1 feature size,
``d_z`` latent size, ``K`` future frames)::

    s_t   proprioception (mocap.observations.proprioception, 15 B - 2)
          | a_{t-1} | a_{t-2}   raw policy actions of the two previous steps ([P]; ``prev_actions``)

  A deliberate departure, not an oversight: VMP Sec. 4 observes a 217-dim vector of root height,
  root velocities, joint states (q, q-dot) and key-body positions in the heading frame (plus the two
  previous actions); this tracker uses the shared PHC proprioception instead (heading-frame body
  positions, rotations and velocities of every body, which contain all of the paper's terms but
  the joint angles themselves), so that every latent space in the framework sees the same robot
  state and the comparison between them is about the latent, not about the observation. The two
  previous actions are the paper's.
    c_t   conditioning, by ``conditioning``:
          M    m_t                                  F
          M5   m_t | m_{t+1} .. m_{t+5}             6 F
          M10  m_t | m_{t+1} .. m_{t+10}            11 F
          L    z_t                                  d_z
          LM   m_t | z_t                            F + d_z

* ``m_t``: the stage-1 per-frame features (:mod:`mocap_vmp.features`) of the reference at the
  step's target time, in its own heading frame (the paper's "same procedure with W = 0"),
  standardized with the VAE's saved statistics (orientation channels untouched).
* Future frames ``m_{t+k}`` (M5/M10) [D]: the reference ``k`` control steps later (clamped to the
  clip's last frame, i.e. edge padding as for windows), expressed in the heading frame of ``m_t``
  (``future_heading: current``, the window convention of stage 1) or each in its own
  (``future_heading: own``); standardized likewise.
* ``z_t``: the VAE encoder's posterior mean of the window centred at the clip frame nearest the
  target time, precomputed for every frame of every clip once when the env / imitator is built.

**Actions** (``action``): ``absolute`` [P: PD targets, Eq. 9 with absolute a_t]: the normalized
map of PHC (``q = offset + scale * a``, :func:`mocap_phc.env.pd_offset_scale`, no per-joint
overrides); ``residual`` [D]: ``q = q^_t + a`` (reference pose plus the action). The paper outputs
the PD targets directly; the absolute map is that up to a fixed per-joint affine normalization.

**Reward** (Eq. 5-8, weights [T1] humanoid column, :class:`VmpRewardWeights`)::

    r = - c_h |h - h^|^2 - c_theta ||R(theta) - R(theta^)||_F^2 - c_v |v - v^|^2 - c_q |q - q^|^2
        - c_qd |qd - qd^|^2 - c_p |p - p^|^2                          (standardized quantities)
        + c_alive
        - c_da |a_t - a_{t-1}|^2 - c_dda |a_t - 2 a_{t-1} + a_{t-2}|^2 - c_tau |tau|^2

``reward_form: exp`` [D] replaces each tracking term by a bounded kernel,
``+ c_g exp(-k e_g / n_g)`` with ``e_g`` the group's squared error above, ``n_g`` its number of
feature dimensions and ``k = exp_scale`` (alive and smoothness terms unchanged). The paper's sum is
far below zero until the policy tracks (about -86 per step here at the start against the +6
alive bonus), so on a small CPU budget its signal is mostly the clamp at zero; the kernel keeps a
gradient everywhere, as DeepMimic / PHC rewards do.

Both sides of the tracking terms are features of :func:`state_features` in their own heading
frame, standardized with the VAE's statistics [P], the std floored at ``reward_std_min`` (0.05 in
natural units) [D] so that features constant in the VAE's data do not dominate. ``a`` in the smoothness terms is the PD target in
rad (``smoothness_on: targets``, [P] a_t are PD targets) or the raw policy action
(``smoothness_on: actions``) [D]; ``tau`` is the simulator's applied joint torque
(``SimState.dof_force``). At an episode start both previous actions are set to the action that
holds the current (reset) pose [D], so the first steps carry no artificial jump penalty.

**Termination** (section 4.6): the end-effector deviation (root-relative, heading frame,
**unstandardized** metres [D, 9.5 item 5]; per ``termination_norm`` the max over end effectors of
the Euclidean distance [D, item 6] or the infinity norm of the stacked vector) above
``termination_threshold`` (t^p = 0.2 m [T1]) for ``termination_persist_s`` (f = 3 s [T1]): a
per-env counter of consecutive steps above the threshold, reset to 0 at the first step at or below
it; the episode terminates at the step where the counter reaches ``round(f / dt)`` (90 at 30 Hz).
Numerical instability also terminates (reward 0). The episode is truncated (bootstrapped) after
``episode_length_s`` (T = 30 s [T1]).

**Reference sampling** [P]: RSI (a clip by the library's weights, a uniform time, the simulator
reset to the reference there). When the reference reaches its clip's end and the episode goes on, a
new clip and time are drawn and the reference jumps there *without* resetting the simulator
(``reference_jump: true``; ``false`` truncates the episode at the clip's end instead).

**Domain randomization** [P section 4.9] (``randomization``, default off;
:mod:`mocap_vmp.randomization`): body masses and ground friction redrawn at every reset of an env,
random pushes (external wrenches on the root, head, hands and feet) on a per-env timer. The
actuator model of Eqs. 9-11 is the simulator's option (``simulator.params.actuator_model``,
:mod:`mocap_sim_mujoco.actuators`).
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from pathlib import Path
from typing import Any, Literal

import numpy as np
import torch
from pydantic import BaseModel, ConfigDict, Field
from torch import Tensor

from mocap.interfaces import Imitator
from mocap.motion.library import grid_start_times
from mocap.observations import proprioception, proprioception_dim
from mocap.rl.env import StepResult
from mocap.rotations import (
    heading_quat_inv,
    matrix_to_sixd,
    quat_apply,
    quat_mul,
    quat_to_matrix,
    sixd_to_matrix,
)
from mocap.skeleton import Skeleton
from mocap.state import HUMANOID_FIELDS, HumanoidState, MotionFrames, Observations, SimState
from mocap_vmp.features import FeatureLayout, clip_starts, standardize
from mocap_vmp.randomization import DomainRandomizationParams, DomainRandomizer

STATE_FORMAT = "mocap_vmp.tracking_env/1"
Conditioning = Literal["M", "M5", "M10", "L", "LM"]
TRACK_TERMS = ("h", "theta", "v", "q", "qd", "p")
SMOOTH_TERMS = ("da", "dda", "tau")


# ------------------------------------------------------------------------------------ params
class VmpRewardWeights(BaseModel):
    """Reward weights (Eq. 6-8) [T1, humanoid column; the robot column is h 0, v 2, q 7, alive 30,
    da 1.5, dda 0.45, tau 1e-4]."""

    model_config = ConfigDict(extra="forbid")

    h: float = Field(0.5, ge=0, description="c^h, root height [T1 0.5]")
    theta: float = Field(1.0, ge=0, description="c^theta, root orientation ||R - R^||_F^2 [T1 1.0]")
    v: float = Field(1.0, ge=0, description="c^v, root linear + angular velocity [T1 1.0]")
    q: float = Field(1.0, ge=0, description="c^q, joint angles [T1 1.0]")
    qd: float = Field(0.1, ge=0, description="c^qd, joint velocities [T1 0.1]")
    p: float = Field(1.0, ge=0, description="c^p, root-relative end-effector positions [T1 1.0]")
    alive: float = Field(6.0, description="c^alive, constant bonus per step [T1 6.0]")
    da: float = Field(0.1, ge=0, description="c^da, action rate |a_t - a_{t-1}|^2 [T1 0.1]")
    dda: float = Field(
        0.01,
        ge=0,
        description="c^dda, action acceleration |a_t - 2 a_{t-1} + a_{t-2}|^2 [T1 0.01]",
    )
    tau: float = Field(1e-5, ge=0, description="c^tau, applied joint torque |tau|^2 [T1 1e-5]")


class VmpTrackerParams(BaseModel):
    """The tracking env and policy interface (module docstring). Tags: [P] paper, [T1] Table 1, [D] ours."""

    model_config = ConfigDict(extra="forbid")

    conditioning: Conditioning = Field(
        "LM",
        description="policy conditioning [P ablations]: M = m_t; M5 / M10 = m_t plus the next 5 / 10 frames; "
        "L = z_t only; LM = m_t and z_t (the paper's method)",
    )
    future_heading: Literal["current", "own"] = Field(
        "current",
        description="M5/M10: future frames in the heading frame of m_t ('current', the window convention) or their own [D]",
    )
    action: Literal["absolute", "residual"] = Field(
        "absolute",
        description="'absolute' = PD targets offset + scale * a (normalized map to the joint ranges; [P] the policy outputs "
        "absolute PD targets) or 'residual' = reference pose + a [D]",
    )
    action_clip: float | None = Field(
        None,
        gt=0,
        description="clamp raw actions to [-clip, clip] (the env's Box bounds); None: unbounded",
    )
    prev_actions: int = Field(
        2,
        ge=0,
        le=2,
        description="previous actions in the observation [P: a_{t-1}, a_{t-2}]",
    )
    sixd: Literal["zhou", "tan_norm"] = Field("zhou", description="6-D rotations in the proprioception [P: Zhou et al.]")
    reward: VmpRewardWeights = Field(default_factory=VmpRewardWeights)
    reward_std_min: float = Field(
        0.05,
        ge=0,
        description="floor on the standardization std used by the reward, natural units (m, rad, m/s, rad/s) [D]: the VAE's "
        "statistics floor features that never vary in its data at ~1e-6, which would turn any error there into ~1e12",
    )
    only_positive_rewards: bool = Field(
        False,
        description="clip each step's total reward at 0 from below [D, legged_gym's only_positive_rewards]: Eq. 6 sums "
        "squared errors over every standardized dimension, so early in training the step reward is far below zero "
        "(measured here: about -86 per step against the +6 alive bonus) and ending the episode as soon as the "
        "termination allows is what PPO learns (episodes stayed at the 3-s minimum); [P] no clipping",
    )
    reward_form: Literal["paper", "exp"] = Field(
        "paper",
        description="tracking terms: 'paper' = -c_g e_g (Eq. 6) or 'exp' = +c_g exp(-exp_scale e_g / n_g) with n_g the "
        "group's feature dimensions [D: a DeepMimic/PHC-style bounded kernel; not in the paper]",
    )
    exp_scale: float = Field(2.0, gt=0, description="k of reward_form 'exp' (per mean squared standardized error) [D]")
    smoothness_on: Literal["targets", "actions"] = Field(
        "targets",
        description="what the action-rate / acceleration penalties see: PD targets in rad ([P] a_t = PD targets) or raw actions [D]",
    )
    termination_threshold: float = Field(0.2, gt=0, description="t^p, m [T1: 0.2 humanoid, 0.3 robot]")
    termination_persist_s: float = Field(3.0, gt=0, description="f, s: the deviation must persist this long [T1: 3.0]")
    termination_norm: Literal["max_euclidean", "inf"] = Field(
        "max_euclidean",
        description="end-effector deviation: max over end effectors of the distance, or the inf-norm of the stacked vector [D]",
    )
    episode_length_s: float = Field(30.0, gt=0, description="T, s: time limit (truncation, bootstrapped) [T1: 30 s]")
    reference_jump: bool = Field(
        True,
        description="at a clip's end jump to a random frame of a new clip without resetting the simulation [P]; false: truncate",
    )
    randomization: DomainRandomizationParams | None = Field(
        None,
        description="domain randomization [P section 4.9: body masses, ground friction, random pushes; "
        "mocap_vmp.randomization]; null = off. The actuator model of Eqs. 9-11 is the simulator's actuator_model option",
    )


@dataclass(frozen=True)
class ConditioningSpec:
    use_m: bool
    future: int
    use_z: bool


def conditioning_spec(mode: str) -> ConditioningSpec:
    """What each ablation feeds the policy (module docstring)."""
    table = {
        "M": ConditioningSpec(True, 0, False),
        "M5": ConditioningSpec(True, 5, False),
        "M10": ConditioningSpec(True, 10, False),
        "L": ConditioningSpec(False, 0, True),
        "LM": ConditioningSpec(True, 0, True),
    }
    if mode not in table:
        raise ValueError(f"unknown conditioning {mode!r}; choose one of {', '.join(table)}")
    return table[mode]


def conditioning_dim(mode: str, feature_dim: int, latent_dim: int) -> int:
    c = conditioning_spec(mode)
    return (feature_dim * (1 + c.future) if c.use_m else 0) + (latent_dim if c.use_z else 0)


# ---------------------------------------------------------------------------------- features
def state_features(state: HumanoidState, ee_index: Tensor, heading_inv: Tensor | None = None) -> Tensor:
    """(N, F) stage-1 per-frame features of a simulated or reference state (same layout and
    conventions as :func:`mocap_vmp.features.window_features`), unstandardized, in the heading
    frame ``heading_inv`` (N, 4) (default: the state's own)."""
    root_pos, root_rot = state.root_pos, state.root_rot
    hinv = heading_quat_inv(root_rot) if heading_inv is None else heading_inv.to(root_rot)
    h = root_pos[:, 2:3]
    theta = matrix_to_sixd(quat_to_matrix(quat_mul(hinv, root_rot)))
    v = torch.cat((quat_apply(hinv, state.root_lin_vel), quat_apply(hinv, state.root_ang_vel)), -1)
    ee = state.body_pos[:, ee_index.to(root_pos.device)] - root_pos[:, None, :]
    p = quat_apply(hinv[:, None, :].expand(*ee.shape[:-1], 4), ee).flatten(1)
    return torch.cat((h, theta, v, state.dof_pos, state.dof_vel, p), -1)


# ------------------------------------------------------------------------------------ reward
def tracking_errors(ref: Tensor, sim: Tensor, layout: FeatureLayout) -> dict[str, Tensor]:
    """Squared errors (N,) per Eq. 6 group between **standardized** feature vectors (N, F); the
    orientation as ``||R(theta) - R(theta^)||_F^2`` (in [0, 8])."""
    s = layout.slices
    out = {}
    for g in TRACK_TERMS:
        if g == "theta":
            d = sixd_to_matrix(ref[..., s[g]]) - sixd_to_matrix(sim[..., s[g]])
            out[g] = d.square().sum((-1, -2))
        else:
            out[g] = (ref[..., s[g]] - sim[..., s[g]]).square().sum(-1)
    return out


def smoothness_errors(a: Tensor, a1: Tensor, a2: Tensor, tau: Tensor) -> dict[str, Tensor]:
    """Eq. 8's squared norms (N,): action rate, action acceleration (second difference), torque."""
    return {
        "da": (a - a1).square().sum(-1),
        "dda": (a - 2.0 * a1 + a2).square().sum(-1),
        "tau": tau.square().sum(-1) if tau.numel() else torch.zeros(a.shape[0], dtype=a.dtype, device=a.device),
    }


def _reward_total(
    track_terms: dict[str, Tensor], smooth: dict[str, Tensor], w: VmpRewardWeights
) -> tuple[Tensor, dict[str, Tensor]]:
    """``c_alive + sum of the weighted tracking terms - sum_s c_s e_s`` and every term by name."""
    any_t = next(iter(track_terms.values()))
    terms: dict[str, Tensor] = {"alive": torch.full_like(any_t, float(w.alive))}
    terms.update({f"track/{g}": v for g, v in track_terms.items()})
    terms.update({f"smooth/{k}": -float(getattr(w, k)) * e for k, e in smooth.items()})
    total = terms["alive"].clone()
    for v in list(terms.values())[1:]:
        total = total + v
    return total, terms


def vmp_reward(track: dict[str, Tensor], smooth: dict[str, Tensor], w: VmpRewardWeights) -> tuple[Tensor, dict[str, Tensor]]:
    """Eq. 5: ``r = -sum_g c_g e_g + c_alive - sum_s c_s e_s``; returns the total and each weighted term
    (``track/<g>``, ``alive``, ``smooth/<s>``; all but ``alive`` are <= 0)."""
    return _reward_total({g: -float(getattr(w, g)) * e for g, e in track.items()}, smooth, w)


def vmp_reward_exp(
    track: dict[str, Tensor], smooth: dict[str, Tensor], w: VmpRewardWeights, dims: dict[str, int], scale: float
) -> tuple[Tensor, dict[str, Tensor]]:
    """``reward_form: exp``: ``r = sum_g c_g exp(-scale e_g / n_g) + c_alive - sum_s c_s e_s`` with
    ``n_g = dims[g]``; same term names as :func:`vmp_reward` (``track/<g>`` here in [0, c_g])."""
    kernels = {g: float(getattr(w, g)) * torch.exp(-scale * e / max(int(dims[g]), 1)) for g, e in track.items()}
    return _reward_total(kernels, smooth, w)


# ------------------------------------------------------------------------------- termination
def end_effector_error(ref_p: Tensor, sim_p: Tensor, norm: str = "max_euclidean") -> Tensor:
    """(N,) deviation of root-relative end-effector positions (N, 3E), metres."""
    d = (ref_p - sim_p).reshape(ref_p.shape[0], -1, 3)
    if norm == "max_euclidean":
        return torch.linalg.vector_norm(d, dim=-1).amax(-1)
    if norm == "inf":
        return d.abs().flatten(1).amax(-1)
    raise ValueError(f"unknown termination_norm {norm!r}")


def persist_steps(persist_s: float, dt: float) -> int:
    """Consecutive control steps that make ``persist_s`` seconds (at least 1)."""
    return max(1, round(persist_s / dt))


def update_counter(counter: Tensor, error: Tensor, threshold: float, steps: int) -> tuple[Tensor, Tensor]:
    """One step of the persistence rule: ``counter + 1`` where ``error > threshold`` (else 0) and
    ``fired = counter >= steps`` (the step where the deviation has lasted ``steps`` steps)."""
    over = error > threshold
    counter = torch.where(over, counter + 1, torch.zeros_like(counter))
    return counter, counter >= steps


# ------------------------------------------------------------------------- the conditioning
class VmpConditioning:
    """Builds ``c_t`` for (clip, time) pairs of a motion library from a trained :class:`VmpLatent`.

    The per-frame latents of ``library`` are the latent's saved ones when they were made on the
    same clips, else encoded here once (posterior means)."""

    def __init__(self, params: VmpTrackerParams, latent: Any, library: Any, dt: float):
        self.params = params
        self.spec = conditioning_spec(params.conditioning)
        self.latent = latent
        self.library = library
        self.layout: FeatureLayout = latent.layout
        self.dt = float(dt)
        dev = library.device
        self.ee_index = latent.ee_index.to(dev)
        self.mean = latent.feat_mean.detach().to(dev, library.dtype)
        self.std = latent.feat_std.detach().to(dev, library.dtype)
        rstd = self.std.clamp_min(params.reward_std_min)
        rstd[self.layout.theta] = 1.0
        self.reward_std = rstd
        self.starts = clip_starts(library).to(dev)
        self.frame_latents: Tensor | None = None
        if self.spec.use_z:
            saved = getattr(latent, "frame_latents", None)
            same = saved is not None and list(getattr(latent, "clip_names", [])) == list(library.clip_names)
            if same and saved.shape[0] == library.total_frames:
                self.frame_latents = saved.detach().to(dev, library.dtype)
            else:
                self.frame_latents = latent.encode_library(library).detach().to(dev, library.dtype)
        self.dim = conditioning_dim(params.conditioning, self.layout.dim, int(latent.latent_dim))

    def standardize(self, x: Tensor) -> Tensor:
        """With the VAE's statistics (the observation's ``m_t``)."""
        return standardize(x, self.mean.to(x), self.std.to(x))

    def reward_standardize(self, x: Tensor) -> Tensor:
        """With the VAE's statistics, std floored at ``reward_std_min`` (the reward's quantities)."""
        return standardize(x, self.mean.to(x), self.reward_std.to(x))

    def frame_rows(self, clip_ids: Tensor, times: Tensor) -> Tensor:
        """(N,) packed row of the clip frame nearest each time (clamped into the clip)."""
        lib = self.library
        c = clip_ids.to(self.starts.device).long()
        k = torch.round(times.to(torch.float64) * lib._fps64[c]).long()
        k = torch.minimum(k.clamp_min(0), lib.num_frames.to(k.device)[c] - 1)
        return self.starts[c] + k

    def __call__(self, ref: HumanoidState, clip_ids: Tensor, times: Tensor) -> tuple[Tensor, Tensor]:
        """(N, C) conditioning and (N, F) the unstandardized own-heading features of ``ref`` (the
        reference at ``times`` of ``clip_ids``)."""
        lib = self.library
        feat = state_features(ref, self.ee_index)
        parts: list[Tensor] = []
        if self.spec.use_m:
            parts.append(self.standardize(feat))
        K = self.spec.future
        if K:
            N = feat.shape[0]
            c = clip_ids.to(lib.device).long()
            dur = lib._dur64.to(lib.device)[c]
            ks = torch.arange(1, K + 1, device=lib.device, dtype=torch.float64)
            t = (times.to(lib.device, torch.float64)[:, None] + ks[None, :] * self.dt).minimum(dur[:, None])  # (N, K)
            fut = clip_frames(lib, c[:, None].expand(N, K).reshape(-1), t.reshape(-1))
            hinv = None
            if self.params.future_heading == "current":
                hinv = heading_quat_inv(ref.root_rot)[:, None, :].expand(N, K, 4).reshape(-1, 4)
            ff = state_features(fut, self.ee_index, hinv).to(feat)
            parts.append(self.standardize(ff).reshape(N, K * feat.shape[-1]))
        if self.spec.use_z:
            assert self.frame_latents is not None
            parts.append(self.frame_latents[self.frame_rows(clip_ids, times)].to(feat))
        return torch.cat(parts, -1), feat


def clip_frames(library: Any, clip_ids: Tensor, times: Tensor) -> MotionFrames:
    """``library.frames`` with the times clamped into ``[0, duration]`` of a *non-looping* reading of
    every clip (a looping clip's time ``duration`` is its last frame, not the next cycle's first)."""
    c = clip_ids.to(library.device).long()
    dur = library._dur64.to(library.device)[c]
    t = times.to(library.device, torch.float64).clamp_min(0.0).minimum((dur - 1e-7).clamp_min(0.0))
    return library.frames(c, t)


def _action_map(skeleton: Skeleton, params: VmpTrackerParams) -> Any:
    from mocap.pd_actions import ActionMap

    return ActionMap.for_skeleton(skeleton, params.action, params.action_clip, {})


def hold_action(action_map: Any, dof_pos: Tensor) -> Tensor:
    """The raw action whose PD target is the pose ``dof_pos`` (absolute map; zeros for residual)."""
    if action_map.mode == "absolute":
        return (dof_pos - action_map.offset.to(dof_pos)) / action_map.scale.to(dof_pos)
    return torch.zeros_like(dof_pos)


def _clean(x: Tensor) -> Tensor:
    return torch.nan_to_num(x.float(), nan=0.0, posinf=0.0, neginf=0.0)


# ---------------------------------------------------------------------------------------- env
class VmpTrackingEnv:
    """N VMP tracking episodes (module docstring); a :class:`mocap.rl.env.VecEnv`.

    Args:
        params: :class:`VmpTrackerParams`.
        skeleton, library, simulator: the humanoid, the clips, N envs.
        latent: the trained :class:`~mocap_vmp.latent.VmpLatent` (statistics, encoder).
        seed: seeds the env's generator (RSI and reference jumps).
    """

    def __init__(
        self,
        params: VmpTrackerParams,
        skeleton: Skeleton,
        library: Any,
        simulator: Any,
        latent: Any,
        *,
        seed: int = 0,
    ):
        self.params = p = params
        self.skeleton = skeleton
        self.library = lib = library
        self.sim = simulator
        self.num_envs = N = int(simulator.num_envs)
        self.device = dev = lib.device
        self.dt = float(simulator.dt)
        self.cond = VmpConditioning(p, latent, lib, self.dt)
        self.layout = self.cond.layout
        self.action_map = _action_map(skeleton, p)
        self.action_space = self.action_map.space
        A = self.num_actions = int(self.action_map.offset.numel())
        self.proprio_dim = proprioception_dim(skeleton.num_bodies) + p.prev_actions * A
        self.obs_dim = self.proprio_dim + self.cond.dim
        self.episode_steps = max(1, round(p.episode_length_s / self.dt))
        # start times on the control grid: the reference of every step is a table lookup (MotionLibrary.use_control_grid)
        self.library.use_control_grid(self.dt, self.episode_steps + 2)
        self.persist = persist_steps(p.termination_persist_s, self.dt)
        # n_g of reward_form 'exp': feature dimensions of each tracking group
        self.track_dims = {g: sl.stop - sl.start for g, sl in self.layout.slices.items() if g in TRACK_TERMS}
        self._gen = torch.Generator(device="cpu")
        self._gen.manual_seed(int(seed))
        self._dur = lib._dur64.to(dev)
        self.clip_ids = torch.zeros(N, dtype=torch.long, device=dev)
        self.target_time = torch.zeros(N, dtype=torch.float64, device=dev)
        self.progress = torch.zeros(N, dtype=torch.long, device=dev)
        self.ee_counter = torch.zeros(N, dtype=torch.long, device=dev)
        self.ep_return = torch.zeros(N, dtype=torch.float64, device=dev)
        self.jumps = torch.zeros(N, dtype=torch.long, device=dev)
        self.hist_actions = torch.zeros(N, 2, A, device=dev)  # raw actions a_{t-1}, a_{t-2}
        self.hist_targets = torch.zeros(N, 2, A, device=dev)  # PD targets of the same steps
        self._ref_feat = torch.zeros(N, self.layout.dim, device=dev)
        self._ref_dof = torch.zeros(N, A, device=dev)
        self._obs: Tensor | None = None
        self.randomizer = DomainRandomizer(p.randomization, simulator, self._gen) if p.randomization is not None else None

    # ----------------------------------------------------------------------------- helpers
    def _observe(self, state: SimState, ids: Tensor | None = None) -> Tensor:
        """Observations of envs ``ids`` (all when None) at their current target time; caches the target's features."""
        c = self.clip_ids if ids is None else self.clip_ids[ids]
        t = self.target_time if ids is None else self.target_time[ids]
        st = state if ids is None else state.index(ids)
        ref = clip_frames(self.library, c, t)
        cond, feat = self.cond(ref, c, t)
        hist = self.hist_actions if ids is None else self.hist_actions[ids]
        obs = self.assemble(st, hist, cond)
        rows = slice(None) if ids is None else ids
        self._ref_feat[rows] = feat.to(self._ref_feat)
        self._ref_dof[rows] = ref.dof_pos.to(self._ref_dof)
        return obs

    def assemble(self, state: HumanoidState, hist_actions: Tensor, cond: Tensor) -> Tensor:
        parts = [_clean(proprioception(state, self.params.sixd))]
        if self.params.prev_actions:
            parts.append(hist_actions[:, : self.params.prev_actions].reshape(hist_actions.shape[0], -1).float())
        parts.append(_clean(cond))
        return torch.cat(parts, -1)

    def _sample_refs(self, n: int) -> tuple[Tensor, Tensor]:
        clips, times = self.library.sample(n, generator=self._gen)
        clips = clips.to(self.device)
        dur = self._dur[clips]
        t0 = torch.minimum(times.to(self.device, torch.float64), (dur - self.dt).clamp_min(0.0))
        return clips, grid_start_times(t0, dur, torch.zeros_like(clips, dtype=torch.bool), self.dt)

    def _reset_envs(self, ids: Tensor) -> None:
        n = int(ids.numel())
        if n == 0:
            return
        clips, t0 = self._sample_refs(n)
        self.clip_ids[ids] = clips
        self.target_time[ids] = t0 + self.dt
        self.progress[ids] = 0
        self.ee_counter[ids] = 0
        self.ep_return[ids] = 0.0
        self.jumps[ids] = 0
        if self.randomizer is not None:
            self.randomizer.on_reset(ids.cpu())
        self.sim.reset(ids, self.library.frames(clips, t0))
        q = self.sim.state.dof_pos[ids].to(self.hist_actions)
        self.hist_actions[ids] = hold_action(self.action_map, q)[:, None, :].expand(n, 2, -1)
        self.hist_targets[ids] = q[:, None, :].expand(n, 2, -1)

    # ---------------------------------------------------------------------------- VecEnv
    def reset(self) -> Tensor:
        self._reset_envs(torch.arange(self.num_envs, device=self.device))
        self._obs = self._observe(self.sim.state)
        return self._obs.clone()

    def step(self, actions: Tensor) -> StepResult:
        if self._obs is None:
            raise RuntimeError("call reset() (or load_state_dict) before step()")
        p, N = self.params, self.num_envs
        a = torch.as_tensor(actions, device=self.device).float()
        if tuple(a.shape) != (N, self.num_actions):
            raise ValueError(f"actions must be ({N}, {self.num_actions}), got {tuple(a.shape)}")
        if p.action_clip is not None:
            a = a.clamp(-p.action_clip, p.action_clip)
        targets = self.action_map(a, self._ref_dof)
        if self.randomizer is not None:
            self.randomizer.before_step()
        state = self.sim.step(targets)
        self.progress += 1

        layout, cond = self.layout, self.cond
        sim_feat = state_features(state, cond.ee_index).to(self._ref_feat)
        track = tracking_errors(
            cond.reward_standardize(self._ref_feat),
            cond.reward_standardize(sim_feat),
            layout,
        )
        x, hist = (targets, self.hist_targets) if p.smoothness_on == "targets" else (a, self.hist_actions)
        tau = state.dof_force.to(a) if state.dof_force.numel() else state.dof_force
        smooth = smoothness_errors(x.float(), hist[:, 0], hist[:, 1], tau)
        if p.reward_form == "exp":
            reward, terms = vmp_reward_exp(track, smooth, p.reward, self.track_dims, p.exp_scale)
        else:
            reward, terms = vmp_reward(track, smooth, p.reward)
        if p.only_positive_rewards:
            reward = reward.clamp_min(0.0)
        ps = layout.slices["p"]
        ee_err = end_effector_error(self._ref_feat[:, ps], sim_feat[:, ps], p.termination_norm)
        ee_err = torch.nan_to_num(ee_err, nan=math.inf)
        self.ee_counter, fired = update_counter(self.ee_counter, ee_err, p.termination_threshold, self.persist)
        unstable = state.unstable.to(self.device).bool() if state.unstable.numel() else torch.zeros(N, dtype=torch.bool, device=self.device)
        unstable = unstable | ~torch.isfinite(reward)
        reward = torch.where(unstable, torch.zeros_like(reward), reward).double()
        terminated = fired | unstable
        self.ep_return += reward
        self.hist_actions = torch.stack((a, self.hist_actions[:, 0]), 1)
        self.hist_targets = torch.stack((targets.float(), self.hist_targets[:, 0]), 1)
        dq = (self._ref_dof - state.dof_pos.to(self._ref_dof)).abs().mean(-1)

        # the reference advances one step; at a clip's end it jumps (no simulator reset) or the episode ends
        self.target_time += self.dt
        clip_over = self.target_time > self._dur[self.clip_ids] + 1e-6
        truncated = self.progress >= self.episode_steps
        if p.reference_jump:
            jump = clip_over & ~terminated & ~truncated
            if bool(jump.any()):
                ids = jump.nonzero().squeeze(-1)
                clips, t = self._sample_refs(int(ids.numel()))
                self.clip_ids[ids] = clips
                self.target_time[ids] = t
                self.jumps[ids] += 1
        else:
            truncated = truncated | clip_over
        truncated = truncated & ~terminated
        done = terminated | truncated

        final_obs = self._observe(state)
        obs = final_obs
        episodes: dict[str, Tensor] = {}
        if bool(done.any()):
            ids = done.nonzero().squeeze(-1)
            episodes = {
                "return": self.ep_return[ids].float().cpu(),
                "length": self.progress[ids].float().cpu(),
                "success": truncated[ids].float().cpu(),
            }
            self._reset_envs(ids)
            obs = final_obs.clone()
            obs[ids] = self._observe(self.sim.state, ids)
        self._obs = obs
        info: dict[str, Any] = {
            **{f"reward/{k}": v.float() for k, v in terms.items()},
            "error/ee_max_m": torch.nan_to_num(ee_err, posinf=0.0),
            "error/joint_mae_deg": torch.nan_to_num(dq, nan=0.0) * (180.0 / math.pi),
            "terminated/ee": fired.float(),
            "terminated/unstable": unstable.float(),
            "reference_jumps": clip_over.float(),
        }
        return StepResult(
            obs=obs.clone(),
            reward=reward.float(),
            terminated=terminated.clone(),
            truncated=truncated.clone(),
            final_obs=final_obs,
            info=info,
            episodes=episodes,
        )

    def close(self) -> None:
        self.sim.close()

    def current_obs(self) -> Tensor:
        if self._obs is None:
            raise RuntimeError("call reset() first")
        return self._obs.clone()

    # -------------------------------------------------------------------------- resume
    def state_dict(self) -> dict[str, Any]:
        """RNG, per-env counters and action history, and the simulator's physics state."""
        if self._obs is None:
            raise RuntimeError("state_dict() before reset()")
        sd: dict[str, Any] = {
            "format": STATE_FORMAT,
            "num_envs": self.num_envs,
            "clip_names": list(self.library.clip_names),
            "generator": self._gen.get_state().clone(),
            **{k: getattr(self, k).cpu().clone() for k in _COUNTERS},
        }
        if hasattr(self.sim, "get_physics_state"):
            sd["physics"] = torch.from_numpy(np.array(self.sim.get_physics_state(), dtype=np.float64, copy=True))
        else:
            s = self.sim.state
            sd["sim_state"] = {f: getattr(s, f).cpu().clone() for f in _HUMANOID_FIELDS}
        if self.randomizer is not None:
            sd["randomization"] = self.randomizer.state_dict()
        return sd

    def load_state_dict(self, state: dict[str, Any]) -> None:
        if state.get("format") != STATE_FORMAT:
            raise ValueError(f"not a VmpTrackingEnv state (format {state.get('format')!r})")
        if int(state["num_envs"]) != self.num_envs:
            raise ValueError(f"state has {state['num_envs']} envs, this env {self.num_envs}")
        if list(state["clip_names"]) != list(self.library.clip_names):
            raise ValueError("the saved env state was made with a different motion set")
        self._gen.set_state(state["generator"].clone())
        for k in _COUNTERS:
            setattr(self, k, state[k].to(self.device).clone())
        ids = torch.arange(self.num_envs)
        if "physics" in state and hasattr(self.sim, "set_physics_state"):
            phys = state["physics"]
            phys = phys.detach().cpu().numpy() if isinstance(phys, Tensor) else np.asarray(phys)
            self.sim.set_physics_state(ids, np.array(phys, dtype=np.float64, copy=True))
        elif "sim_state" in state:
            self.sim.reset(
                ids,
                HumanoidState(**{k: v.to(self.device) for k, v in state["sim_state"].items()}),
            )
        else:
            raise ValueError("the saved env state has no simulator state usable by this simulator")
        if self.randomizer is not None and "randomization" in state:
            self.randomizer.load_state_dict(state["randomization"])
        self._obs = self._observe(self.sim.state)


_COUNTERS = (
    "clip_ids",
    "target_time",
    "progress",
    "ee_counter",
    "ep_return",
    "jumps",
    "hist_actions",
    "hist_targets",
)
_HUMANOID_FIELDS = HUMANOID_FIELDS


# ----------------------------------------------------------------------------- the component
class VmpTracker:
    """The ``vmp_tracker`` imitator component: builds :class:`VmpTrackingEnv` for PPO and, when
    loaded from a ``vmp.pt``, holds the trained VAE and policy (:meth:`imitator`).

    ``make_env`` needs the trained VAE: ``latent`` given here, or ``ctx.vmp_latent`` (set by the
    ``vmp_track`` trainer), or the upstream ``latent`` stage's checkpoint."""

    def __init__(
        self,
        params: VmpTrackerParams,
        skeleton: Skeleton,
        latent: Any = None,
        policy: Any = None,
        device: Any = "cpu",
    ):
        self.params = params
        self.skeleton = skeleton
        self.latent = latent
        self.policy = policy
        self.device = torch.device(device)

    def _latent(self, ctx: Any) -> Any:
        if self.latent is not None:
            return self.latent
        latent = getattr(ctx, "vmp_latent", None)
        if latent is not None:
            return latent
        upstream = getattr(ctx, "upstream", {}) or {}
        if "latent" in upstream and upstream["latent"].checkpoint is not None:
            return ctx.stage_component("latent", checkpoint=upstream["latent"].checkpoint)
        raise ValueError(
            "vmp_tracker needs the trained VMP VAE: train it with the latent stage's `vmp_track` trainer "
            "(latent: {name: vmp, trainer: {name: vmp_track}}), which trains the VAE and then this tracker"
        )

    def make_env(self, ctx: Any, num_envs: int) -> VmpTrackingEnv:
        from mocap.motion.library import MotionLibrary

        latent = self._latent(ctx)
        motion_set = ctx.build("motions").load(self.skeleton)
        for path, reason in getattr(motion_set, "skipped", []):
            ctx.console.print(f"[yellow]skipped[/] {path}: {reason}")
        library = MotionLibrary(motion_set, self.skeleton)
        sim = ctx.build("simulator", skeleton=self.skeleton, num_envs=num_envs, seed=ctx.seed)
        return VmpTrackingEnv(self.params, self.skeleton, library, sim, latent.to("cpu"), seed=ctx.seed)

    def imitator(self, library: Any) -> VmpImitator:
        if self.latent is None or self.policy is None:
            raise RuntimeError("this vmp_tracker has no trained VAE and policy (build it with a vmp.pt checkpoint)")
        return VmpImitator(self.params, self.skeleton, self.latent, self.policy, library, self.device)


# ------------------------------------------------------------------------------ the imitator
class VmpImitator(Imitator):
    """The trained tracker as an :class:`~mocap.interfaces.Imitator` for the imitation protocol.

    ``observe(state, reference)`` reads the reference's ``clip_ids`` and ``times`` (frames of
    ``library``) for the future frames and ``z_t``. It keeps the previous two actions per env; an
    env's history restarts (the hold-the-current-pose action) when the batch size changes, its clip
    changes or its reference time goes back. The history advances in :meth:`to_pd_targets` (so
    :meth:`act` and ``policy_output`` + ``to_pd_targets`` both keep it)."""

    def __init__(
        self,
        params: VmpTrackerParams,
        skeleton: Skeleton,
        latent: Any,
        policy: Any,
        library: Any,
        device: Any = "cpu",
        dt: float | None = None,
    ):
        self.params = params
        self.skeleton = skeleton
        self.latent = latent.to("cpu").eval()
        self.policy = policy
        self.library = library
        self.device = torch.device(device)
        self.dt = float(dt) if dt is not None else float(1.0 / float(library.fps[0]))
        self.cond = VmpConditioning(params, self.latent, library, self.dt)
        self.action_map = _action_map(skeleton, params)
        A = int(self.action_map.offset.numel())
        self.obs_dim = proprioception_dim(skeleton.num_bodies) + params.prev_actions * A + self.cond.dim
        self._hist_a: Tensor | None = None
        self._hist_t: Tensor | None = None
        self._last_clip: Tensor | None = None
        self._last_time: Tensor | None = None

    def reset(self) -> None:
        self._hist_a = self._hist_t = self._last_clip = self._last_time = None

    def observe(self, state: SimState, reference: MotionFrames) -> Observations:
        lib = self.library
        c = reference.clip_ids.to(lib.device).long()
        t = reference.times.to(lib.device, torch.float64)
        n = c.shape[0]
        q = state.dof_pos.float().cpu()
        if self._hist_a is None or self._hist_a.shape[0] != n:
            fresh = torch.ones(n, dtype=torch.bool)
            self._hist_a = torch.zeros(n, 2, q.shape[-1])
            self._hist_t = torch.zeros(n, 2, q.shape[-1])
        else:
            assert self._last_clip is not None and self._last_time is not None
            fresh = (c.cpu() != self._last_clip) | (t.cpu() < self._last_time - 1e-6)
        if bool(fresh.any()):
            assert self._hist_t is not None
            self._hist_a[fresh] = hold_action(self.action_map, q[fresh])[:, None, :].expand(-1, 2, -1)
            self._hist_t[fresh] = q[fresh][:, None, :].expand(-1, 2, -1)
        self._last_clip, self._last_time = c.cpu().clone(), t.cpu().clone()
        cond, _ = self.cond(reference, c, t)
        proprio = [_clean(proprioception(state, self.params.sixd)).cpu()]
        if self.params.prev_actions:
            proprio.append(self._hist_a[:, : self.params.prev_actions].reshape(n, -1))
        return Observations(
            proprio=torch.cat(proprio, -1),
            goal=_clean(cond).cpu(),
            extra={"ref_dof_pos": reference.dof_pos},
        )

    def policy_output(self, obs: Observations, deterministic: bool = True) -> Tensor:
        assert obs.goal is not None
        x = torch.cat((obs.proprio, obs.goal), -1).to(self.device)
        with torch.no_grad():
            if deterministic or not hasattr(self.policy, "act"):
                out = self.policy.mean_action(x) if hasattr(self.policy, "mean_action") else self.policy(x)
            else:
                out = self.policy.act(x)[0]
        return out.to(obs.proprio.device)

    def to_pd_targets(self, obs: Observations, output: Tensor) -> Tensor:
        a = output.float()
        if self.params.action_clip is not None:
            a = a.clamp(-self.params.action_clip, self.params.action_clip)
        targets = self.action_map(a, obs.extra.get("ref_dof_pos"))
        if self._hist_a is not None and self._hist_a.shape[0] == a.shape[0]:
            assert self._hist_t is not None
            self._hist_a = torch.stack((a.cpu(), self._hist_a[:, 0]), 1)
            self._hist_t = torch.stack((targets.float().cpu(), self._hist_t[:, 0]), 1)
        return targets

    def act(self, obs: Observations, deterministic: bool = True) -> Tensor:
        return self.to_pd_targets(obs, self.policy_output(obs, deterministic))


# -------------------------------------------------------------------------------- loading
TRACKER_KEY = "tracker"


def load_vmp_file(path: str | Path, skeleton: Skeleton, device: Any = "cpu") -> tuple[Any, Any, VmpTrackerParams]:
    """(VmpLatent, ActorCritic, VmpTrackerParams) from a combined ``vmp.pt`` of the ``vmp_track`` trainer."""
    from mocap.checkpoint import load_checkpoint
    from mocap.rl.networks import ActorCritic
    from mocap_vmp.latent import VmpParams, make_vmp

    data = load_checkpoint(Path(path), map_location="cpu")
    tracker = data.get(TRACKER_KEY)
    if tracker is None:
        from mocap.checkpoint import CheckpointError

        raise CheckpointError(f"{path}: no tracking policy in this vmp checkpoint (a stage-1-only file; train with the vmp_track trainer)")
    config = dict(data.get("config") or {})
    vparams = VmpParams(**{k: v for k, v in config.items() if k in VmpParams.model_fields})
    latent = make_vmp(vparams, skeleton=skeleton, checkpoint=path, device="cpu")
    policy = ActorCritic.from_config(tracker["policy_config"])
    policy.load_state_dict(tracker["policy_state"])
    policy = policy.to(device).eval()
    return latent, policy, VmpTrackerParams(**tracker["params"])


def vmp_imitator(
    latent_checkpoint: str | Path,
    skeleton: Skeleton,
    library: Any,
    device: Any = "cpu",
    dt: float | None = None,
) -> VmpImitator:
    """The trained VMP tracker of a ``vmp.pt`` as an :class:`Imitator` over ``library``'s clips
    (``dt``: the control step, default one frame of the library's first clip)."""
    latent, policy, params = load_vmp_file(latent_checkpoint, skeleton, device)
    imitator = VmpImitator(params, skeleton, latent, policy, library, device, dt)
    if policy.obs_dim != imitator.obs_dim:
        raise ValueError(f"{latent_checkpoint}: the policy takes {policy.obs_dim} observation dims, the tracker builds {imitator.obs_dim}")
    return imitator


def make_vmp_tracker(
    params: VmpTrackerParams | None = None,
    *,
    skeleton: Skeleton,
    checkpoint: str | Path | None = None,
    device: torch.device | str = "cpu",
) -> VmpTracker:
    """Registry factory (imitator ``vmp_tracker``): an untrained tracker (for ``make_env``) or, with a
    ``vmp.pt`` of the ``vmp_track`` trainer, the trained VAE and policy (the saved tracker params win)."""
    params = params or VmpTrackerParams()
    if checkpoint is None:
        return VmpTracker(params, skeleton, device=device)
    latent, policy, saved = load_vmp_file(checkpoint, skeleton, device)
    return VmpTracker(saved, skeleton, latent, policy, device)


__all__ = [
    "VmpConditioning",
    "VmpImitator",
    "VmpRewardWeights",
    "VmpTracker",
    "VmpTrackerParams",
    "VmpTrackingEnv",
    "conditioning_dim",
    "conditioning_spec",
    "end_effector_error",
    "load_vmp_file",
    "make_vmp_tracker",
    "persist_steps",
    "smoothness_errors",
    "state_features",
    "tracking_errors",
    "update_counter",
    "vmp_imitator",
    "vmp_reward",
    "vmp_reward_exp",
]
