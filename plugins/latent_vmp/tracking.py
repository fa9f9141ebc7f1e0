"""VMP stage II: the latent-conditioned tracking policy's environment, reward, termination and imitator.

Tags: [P] the paper (VMP, Serifi et al. 2024, Sec. 3.2 and 4.1), [T1] its Table 1, [D] our decision where
the paper is silent (our choice; the paper does not specify), [C] none (the paper has no public code).

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
The sum is a :class:`mocap.episodes.RewardTerms` over the terms ``alive`` (1), ``track/<g>`` (``e_g``
or the kernel) and ``smooth/<s>`` (``e_s``) with the weights above (``vmp_reward_weights``); each
term is logged unweighted as ``reward/<term>``.

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

The code is split over modules of this package (all names re-exported here):
:mod:`mocap_vmp.tracking_params` (params, conditioning table), :mod:`mocap_vmp.tracking_reward`
(features, reward, termination), :mod:`mocap_vmp.tracking_conditioning` (``c_t``, action helpers),
:mod:`mocap_vmp.tracking_env` (:class:`VmpTrackingEnv`); the tracker component, imitator and
loading stay here.
"""

from __future__ import annotations

from pathlib import Path
from typing import Any

import torch
from torch import Tensor

from mocap.interfaces import Imitator
from mocap.observations import proprioception, proprioception_dim
from mocap.rl.networks import ActorCritic
from mocap.skeleton import Skeleton
from mocap.state import MotionFrames, Observations, SimState
from mocap_vmp.tracking_conditioning import VmpConditioning, _action_map, _clean, clip_frames, hold_action
from mocap_vmp.tracking_env import STATE_FORMAT, VmpTrackingEnv
from mocap_vmp.tracking_params import (
    Conditioning,
    ConditioningSpec,
    VmpRewardWeights,
    VmpTrackerParams,
    conditioning_dim,
    conditioning_spec,
)
from mocap_vmp.tracking_reward import (
    REWARD_TERMS,
    SMOOTH_TERMS,
    TRACK_TERMS,
    end_effector_error,
    persist_steps,
    smoothness_errors,
    state_features,
    tracking_errors,
    update_counter,
    vmp_reward_terms,
    vmp_reward_weights,
)


# ----------------------------------------------------------------------------- the component
class VmpTracker:
    """The ``vmp_tracker`` imitator component: builds :class:`VmpTrackingEnv` for PPO and, when
    loaded from a ``vmp.pt``, holds the trained VAE and policy (:meth:`imitator`).

    ``make_env`` needs the trained VAE: ``latent`` given here (the ``vmp_track`` trainer does), or the
    upstream ``latent`` stage's checkpoint."""

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
        upstream = ctx.upstream
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
        for path, reason in motion_set.skipped:
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
        policy: ActorCritic,
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
            out = self.policy.mean_action(x) if deterministic else self.policy.act(x)[0]
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
    "REWARD_TERMS",
    "SMOOTH_TERMS",
    "STATE_FORMAT",
    "TRACK_TERMS",
    "Conditioning",
    "ConditioningSpec",
    "VmpConditioning",
    "VmpImitator",
    "VmpRewardWeights",
    "VmpTracker",
    "VmpTrackerParams",
    "VmpTrackingEnv",
    "clip_frames",
    "conditioning_dim",
    "conditioning_spec",
    "end_effector_error",
    "hold_action",
    "load_vmp_file",
    "make_vmp_tracker",
    "persist_steps",
    "smoothness_errors",
    "state_features",
    "tracking_errors",
    "update_counter",
    "vmp_imitator",
    "vmp_reward_terms",
    "vmp_reward_weights",
]
