"""The params of the ``phc`` imitator (:class:`PHCParams`, re-exported by :mod:`mocap_phc.imitator`, whose
docstring explains the defaults) and of its fail-state recovery goal (:class:`RecoveryGoalParams`,
re-exported by :mod:`mocap_phc.recovery`, which documents it). Torch-free, so that validating a spec
(``mocap validate``) and listing the plugins import no torch.
"""

from __future__ import annotations

from typing import TYPE_CHECKING, Literal

from pydantic import BaseModel, ConfigDict, Field, field_validator, model_validator

from mocap.fail_state_params import FailStateParams, GetUpStartParams, check_getup_starts
from mocap.imitation_reward_params import DEFAULT_SCALES, DEFAULT_WEIGHTS
from mocap.noisy import NoiseLevel
from mocap.start_sampling_params import StartSamplingParams

if TYPE_CHECKING:  # pragma: no cover
    from mocap.skeleton import Skeleton
    from mocap_phc.env import ActionMap, PHCObservation


#: the reward terms of the imitation env (:class:`mocap.episodes.RewardTerms`; which ones a configuration declares:
#: :meth:`PHCParams.reward_term_weights`)
REWARD_TERMS = ("imitation", "point", "energy", "amp")


class RecoveryGoalParams(BaseModel):
    model_config = ConfigDict(extra="forbid")
    form: Literal["paper", "code"] = Field(
        "paper", description="'paper': root velocities stay the reference's; 'code' ([C] zero_out_far): all velocities are the simulated ones"
    )
    close_distance: float = Field(0.5, gt=0, description="root distance up to which the full imitation goal is used, m ([P] 0.5; [C] 0.25)")
    far_distance: float = Field(5.0, gt=0, description="the reference root is pulled to at most this distance, m ([P] 5; [C] 3)")
    reward: Literal["imitation", "point"] = Field(
        "imitation",
        description="task reward while far (root farther than close_distance before the step): 'point' = PHC Eq. 4's "
        "point-goal term r = d_{t-1} - d_t (the decrease of the root-to-reference-root distance, m per control step; "
        "[P] for the recovery primitive and the composer) or 'imitation' = the imitation reward as everywhere else",
    )
    point_form: Literal["paper", "code"] = Field(
        "paper",
        description="the point-goal term: 'paper' = d_{t-1} - d_t (PHC Eq. 4); 'code' = 9 min(d_{t-1} - d_t, 1/3) (the "
        "official code's compute_point_goal_reward: scaled and clipped)",
    )
    far_energy_weight: float = Field(
        0.1,
        ge=0.0,
        description="weight of the energy penalty while far with reward 'point' (PHC Eq. 4: 0.5 r^point + 0.5 r^amp + "
        "0.1 r^energy; [C] keeps the penalty inside the task reward with a smaller coefficient instead); 1 = unchanged",
    )


class TerminationCurriculum(BaseModel):
    """A loose-to-tight termination distance: ``start`` m at the first training step, moving linearly
    to the rule's threshold over ``env_steps`` env steps (counted by the env over all its envs), then
    held. Neither PHC's paper nor its code anneals it (fixed 0.5 m mean / 0.25 m any body); loosening
    early lets the policy practise the rest of a clip it would otherwise lose in its first second
    (issue lever; the linear form is our choice)."""

    model_config = ConfigDict(extra="forbid")
    start: float = Field(0.5, gt=0.0, description="m, the threshold at the first training step")
    env_steps: int = Field(5_000_000, ge=1, description="env steps over which the threshold reaches the rule's")


class ContactRules(BaseModel):
    """Which bodies of the humanoid may touch the ground, per clip; a contact by any other body ends
    the episode (logged as ``terminated/fall``). Not in PHC, whose imitation never terminates on
    contacts (only on the tracking distance); MimicKit's per-motion contact bodies do this, so that
    a walking clip is not practised on the knees while a roll or a get-up may touch with anything.

    A clip takes the body list of the first key of ``allowed`` its name matches (``fnmatch``
    globs, in order); a clip that matches none takes ``default`` (None: the skeleton's feet). Body
    lists are globs too; ``["*"]`` lets every body touch (never terminated by contact)."""

    model_config = ConfigDict(extra="forbid")
    allowed: dict[str, list[str]] = Field(
        default_factory=dict, description="clip-name glob -> body-name globs allowed to touch the ground (first matching key wins)"
    )
    default: list[str] | None = Field(None, description="body-name globs of the clips no key matches; None: the skeleton's feet")
    fall_height: float | None = Field(None, gt=0.0, description="only count contacts of bodies below this height, m (None: every contact)")


class PHCParams(BaseModel):
    """Parameters of the PHC / PHC+ imitator ([P] paper value, [C] official code value)."""

    model_config = ConfigDict(extra="forbid")

    # ------------------------------------------------------------------------- observation
    obs: Literal["rot", "keypoint"] = Field(
        "rot",
        description="imitation goal: 'rot' = rotation + keypoint goal (24 per body, [P]/[C] obs_v 6) or "
        "'keypoint' = keypoints only (9 per body, [P] keypoint model, [C] obs_v 7)",
    )
    goal_frames: int = Field(
        1,
        ge=1,
        le=8,
        description="reference frames in the imitation goal: the next one (t + 1) and goal_frames - 1 later ones, each a goal "
        "block against the current state. [P] and the ICCV models of [C]: 1 (the paper names it a limitation); [C] option "
        "fut_tracks (its PHC-Fut model) observes several; MimicKit's tracking env too",
    )
    sixd: Literal["zhou", "tan_norm"] = Field(
        "zhou",
        description="6-D rotation features: 'zhou' = first two matrix columns ([P], Zhou et al.) or 'tan_norm' = rotated x and z axes ([C])",
    )
    # ------------------------------------------------------------------------------ reward
    reward_form: Literal["paper", "code"] = Field(
        "paper",
        description="imitation reward errors: 'paper' = norms exp(-k ||x^ - x||) (mean over bodies of the "
        "per-body norm / rotation angle) or 'code' = mean squared components exp(-k mean (x^ - x)^2)",
    )
    reward_weights: tuple[float, float, float, float] = Field(
        DEFAULT_WEIGHTS, description="(w_pos, w_rot, w_vel, w_ang_vel); [C] and PULSE Table 4: 0.5, 0.3, 0.1, 0.1 (not in the PHC paper)"
    )
    reward_scales: tuple[float, float, float, float] = Field(
        DEFAULT_SCALES, description="(k_pos, k_rot, k_vel, k_ang_vel) in exp(-k e); [P]/[C]: 100, 10, 0.1, 0.1"
    )
    energy_form: Literal["paper", "code"] = Field(
        "code",
        description="energy penalty: 'paper' = -c sum (tau q-dot)^2 as printed, or 'code' = -c sum |tau q-dot| (power, as in "
        "Fu et al. whom the paper cites), zero for the first 3 steps of an episode. Default 'code': the printed square "
        "gives about -10^3 per step on amp right after RSI (measured), drowning the imitation reward (<= 1)",
    )
    energy_coef: float = Field(0.0005, ge=0.0, description="energy coefficient c; [P]/[C] primitives 0.0005 ([C] composer/get-up 0.00005); 0 disables")
    reward_terms: dict[str, float] = Field(
        default_factory=dict,
        description="reward term name -> weight, replacing that term's default weight in r = sum_k w_k r_k (the env logs "
        "each unweighted r_k as reward/<name>). Terms: 'imitation' (the imitation reward), 'point' (PHC Eq. 4's point-goal "
        "reward while far; only with recovery_goal.reward 'point'), 'energy' (the energy penalty), 'amp' (the discriminator "
        "reward; only with amp). Default weights: 1 each without amp; with amp, amp_energy_mix 'paper' = imitation/point "
        "task_reward_weight, amp amp_reward_weight, energy 1, and 'code' = imitation/point/energy task_reward_weight, amp "
        "amp_reward_weight. A term this configuration does not have is an error when the env is built; {} = the defaults",
    )
    # ------------------------------------------------------------------------- termination
    termination: Literal["paper", "code"] = Field(
        "paper",
        description="early termination: 'paper' = mean distance of the checked bodies > threshold (RET, 0.5 m) or "
        "'code' = any checked body > threshold (0.25 m) after the first step",
    )
    termination_threshold: float | None = Field(None, gt=0.0, description="m; None: 0.5 for 'paper', 0.25 for 'code'")
    termination_curriculum: TerminationCurriculum | None = Field(
        None,
        description="anneal the termination threshold from `start` to termination_threshold over `env_steps` training "
        "env steps (None: fixed, as [P] and [C]); the evaluation protocol is not affected",
    )
    termination_grace: int | None = Field(
        None, ge=0, description="steps after a reset that are never checked; None: 0 for 'paper', 1 for 'code' ([C] progress_buf > 1)"
    )
    termination_exclude: list[str] | None = Field(
        None, description="bodies not checked (RET: ankles and toes); None: the skeleton's feet (smpl: ankles + toes; amp: feet)"
    )
    fall_check: bool = Field(False, description="also terminate when a non-foot body touches the ground (not PHC imitation; ASE/AMP style)")
    fall_height: float | None = Field(None, gt=0.0, description="with fall_check: only count contacts of bodies below this height, m (ASE: 0.15)")
    contact_rules: ContactRules | None = Field(
        None,
        description="per-clip bodies allowed to touch the ground; any other contact terminates (MimicKit-style; not PHC); "
        "replaces fall_check's feet-only rule. None: no contact termination ([P]/[C] PHC)",
    )
    # ------------------------------------------------------------------------------ action
    action: Literal["absolute", "residual"] = Field(
        "absolute",
        description="'absolute' = PD target offset + scale * a ([P]/[C]: PHC removed residual actions) or "
        "'residual' = next reference pose + a (UHC-style; cheaper early learning on CPU, measured here)",
    )
    action_clip: float | None = Field(
        None, gt=0.0, description="clamp actions to [-clip, clip] (the env's Box bounds); None: unbounded (the committed residual recipe: 3)"
    )
    action_scale_overrides: dict[str, float] = Field(
        default_factory=lambda: {"*Knee_y": 5.0},
        description="absolute mode: DoF-name glob -> action scale, rad ([C] 'stronger knee': knee y = 5)",
    )
    # ---------------------------------------------------------------------------- episodes
    episode_steps: int = Field(300, ge=1, description="time limit in control steps ([C] 300 = 10 s at 30 Hz); truncation, bootstrapped")
    loop_cycles: float | None = Field(
        None,
        gt=0,
        description="a training episode of a looping clip ends (truncated, bootstrapped: not a failure) after this many "
        "periods of the clip from its start; None: it loops until episode_steps, as DeepMimic and MimicKit do with "
        "their looping clips (PHC's AMASS clips do not loop). The evaluation plays each clip once "
        "(bench/clip_failures.py: looping clips then fail almost every 10 s training episode on a later repeat)",
    )
    start_sampling: StartSamplingParams = Field(
        default_factory=StartSamplingParams,
        description="where in a clip episodes start: 'uniform' (DeepMimic / PHC RSI) or 'adaptive' (failure-driven time bins, "
        "BeyondMimic; mocap.start_sampling)",
    )
    control_grid: bool = Field(
        True,
        description="episode start times on the control-rate grid (t0 = j dt, j uniform over the clip's grid times) and the "
        "reference read from a table precomputed at those times (MotionLibrary.use_control_grid; the speed path). False: "
        "continuous start times, the reference interpolated and run through forward kinematics every step (DeepMimic's "
        "and PHC's continuous phase; identical frames at grid times)",
    )
    fail_states: FailStateParams | None = Field(
        None,
        description="fallen and far episode starts with a grace window (PHC+ fail-state recovery, mocap_phc.recovery); None: RSI only",
    )
    getup_starts: GetUpStartParams | None = Field(
        None,
        description="a fallen start (fail_states.fall_init_prob) tracks the get-up clip that lies like the humanoid, turned and moved onto it, "
        "then holds its last frame at rest (mocap.getup_starts; [I], the training side of `mocap recover --planner getup`: PHC learns "
        "the get-up with a primitive of its own, its code with an AMP-only phase). None: the RSI clip's reference (PHC)",
    )
    reference_noise: NoiseLevel | None = Field(
        None,
        description="train on references with synthetic estimator noise (mocap.noisy: joint and root jitter, dropped frames): "
        "the policy observes the noisy reference and its residual actions are relative to it, while the reward, termination "
        "and the hard-negative evaluation use the clean clip ([I], not in PHC, which trains on clean AMASS; for avatars driven "
        "by video pose estimators, what `mocap eval-noisy` measures). None: clean references",
    )
    reference_noise_every: int = Field(1, ge=1, description="PPO iterations between fresh draws of the reference noise")
    recovery_goal: RecoveryGoalParams | None = Field(
        None,
        description="fail-state recovery goal (PHC Eq. 3, mocap_phc.recovery): farther than close_distance from the reference root, "
        "the goal keeps only the root (a point goal); None: always the full imitation goal (PHC primitives)",
    )
    # ----------------------------------------------------------------------- hard negatives
    hard_negative: bool = Field(True, description="PHC+ soft hard-negative mining: clip sampling weights follow per-clip failure counts ([C] auto_pmcp_soft)")
    hard_negative_floor: float = Field(0.2, ge=0.0, le=1.0, description="share of sampling mass kept on the base weights so that no clip goes to 0 (PHC+: 0)")
    hard_negative_decay: float = Field(1.0, gt=0.0, le=1.0, description="failure counts are multiplied by this before each update (PHC: 1)")
    update_every: int = Field(256, ge=1, description="finished training episodes between weight updates from their failure rates")
    eval_every: int = Field(100, ge=0, description="trainer iterations between evaluate_clips runs (every clip from frame 0, deterministic); 0 disables")
    eval_num_envs: int = Field(64, ge=1, description="clips evaluated in parallel by evaluate_clips")
    eval_threshold: float = Field(0.5, gt=0.0, description="evaluate_clips failure: mean body error above this, m ([P]/[C] evaluation 0.5)")

    # -------------------------------------------------------------------- AMP (PHC+ style reward)
    amp: bool = Field(
        False,
        description="add the AMP discriminator reward r = w_task r_task + w_amp r_amp ([P] PHC Eq. 1 / PULSE Eq. 5); "
        "off until PHC+ training is run (mocap_phc.amp)",
    )
    amp_loss: Literal["lsgan", "bce"] = Field(
        "lsgan",
        description="discriminator objective: 'lsgan' = AMP paper least squares, GP w/2 with w = 10, reward max(0, 1 - (D-1)^2/4) "
        "([P] 'same as AMP') or 'bce' = BCE on logits, GP 5, logit reg 0.01, weight decay 1e-4, coef 5, reward "
        "-2 log(max(1 - sigmoid(D), 1e-4)) ([C])",
    )
    amp_history: int = Field(10, ge=1, description="AMP observation frames per discriminator input ([P]/[C] 10)")
    amp_hidden: list[int] = Field(default_factory=lambda: [1024, 512], description="discriminator ReLU MLP widths ([C] [1024, 512])")
    amp_joints: Literal["rot6d", "dof"] = Field(
        "rot6d", description="AMP joint features: local rotations as tan-norm 6-D ([C]) or hinge angles (compact for hinge skeletons)"
    )
    amp_key_bodies: list[str] | None = Field(
        None, description="bodies whose root-relative positions enter the AMP observation; None: the skeleton's end effectors ([C] ankles + wrists)"
    )
    amp_exclude: list[str] = Field(
        default_factory=list,
        description="bodies whose joint rotations and DoF velocities are left out of the AMP observation; [] keeps every "
        "joint. [C] build_amp_observations_smpl drops the hands and toes: [L_Hand, R_Hand, L_Toe, R_Toe] with "
        "amp_key_bodies [R_Ankle, L_Ankle, R_Wrist, L_Wrist] gives its 196 features per frame on smpl ([P] does not say)",
    )
    amp_lr: float = Field(
        2e-5, gt=0.0, description="discriminator Adam learning rate ([C] it shares the policy optimizer, PHC+ lr 2e-5; small CPU runs want ~1e-4)"
    )
    amp_batch: int = Field(512, ge=2, description="demo and policy windows per discriminator step ([C] amp_batch_size 512)")
    amp_updates_per_iteration: int = Field(5, ge=0, description="discriminator steps per PPO iteration ([C]: one per PPO minibatch step; [I] 5)")
    amp_grad_penalty: float | None = Field(None, ge=0.0, description="None: 10 for lsgan (applied as w/2) and 5 for bce")
    amp_reward_scale: float | None = Field(None, gt=0.0, description="None: 1 for lsgan, 2 for bce ([C] disc_reward_scale)")
    task_reward_weight: float = Field(0.5, ge=0.0, description="w_task ([P]/[C] 0.5)")
    amp_reward_weight: float = Field(0.5, ge=0.0, description="w_amp ([P]/[C] 0.5)")
    amp_energy_mix: Literal["paper", "code"] = Field(
        "paper",
        description="where the energy penalty goes when amp is on: 'paper' = r = w_task r^g + w_amp r^amp + r^energy (Eq. 1) or "
        "'code' = w_task (r^g + r^energy) + w_amp r^amp (the code adds it to the task reward)",
    )
    amp_replay_size: int = Field(200_000, ge=1, description="policy-sample replay buffer ([C] 200,000)")
    amp_replay_keep_prob: float = Field(0.01, gt=0.0, le=1.0, description="keep probability once the replay buffer has filled ([C] 0.01)")
    amp_demo_buffer_size: int = Field(200_000, ge=1, description="demo-window ring buffer, refilled with amp_batch fresh windows per step ([C] 200,000)")

    @model_validator(mode="after")
    def _getup_starts_need_fallen_starts(self) -> "PHCParams":
        check_getup_starts(self.getup_starts, self.fail_states)
        if self.getup_starts is not None and self.amp:
            raise ValueError("getup_starts with amp: the AMP window of a get-up start would be made from the wrong clip; use one or the other")
        return self

    @field_validator("reward_terms")
    @classmethod
    def _known_reward_terms(cls, value: dict[str, float]) -> dict[str, float]:
        unknown = sorted(set(value) - set(REWARD_TERMS))
        if unknown:
            raise ValueError(f"unknown reward term(s) {', '.join(unknown)}; the terms are {', '.join(REWARD_TERMS)}")
        return value

    def reward_term_weights(self) -> dict[str, float]:
        """The default weights of the reward terms this configuration declares, in summation order
        (the order reproduces the env's historical float arithmetic; ``reward_terms`` overrides them)."""
        point = self.recovery_goal is not None and self.recovery_goal.reward == "point"
        task = self.task_reward_weight if self.amp else 1.0
        weights = {"imitation": task, **({"point": task} if point else {})}
        if not self.amp:
            weights["energy"] = 1.0
        elif self.amp_energy_mix == "code":  # w_task (r^g + r^energy) + w_amp r^amp
            weights.update(energy=task, amp=self.amp_reward_weight)
        else:  # Eq. 1: w_task r^g + w_amp r^amp + r^energy
            weights.update(amp=self.amp_reward_weight, energy=1.0)
        return weights

    def observation(self) -> PHCObservation:
        from mocap_phc.env import PHCObservation

        return PHCObservation(self.obs, self.sixd, self.recovery_goal, self.goal_frames)

    def action_map(self, skeleton: Skeleton) -> ActionMap:
        from mocap_phc.env import ActionMap

        return ActionMap.for_skeleton(skeleton, self.action, self.action_clip, self.action_scale_overrides)


__all__ = ["REWARD_TERMS", "PHCParams", "RecoveryGoalParams"]
