"""The params of the built-in tasks, torch-free so that validating a spec (``mocap validate``) and
listing the plugins import no torch. Each task's module documents its params and re-exports them
(:class:`SpeedParams` from :mod:`mocap_tasks.speed`, ...); :class:`FallParams` is shared by every task
(re-exported by :mod:`mocap_tasks.common`). The tracking tasks' params: :mod:`mocap_tasks.tracking_params`.
"""

from __future__ import annotations

from typing import Literal

from mocap_sim_mujoco.mujoco_params import TerrainParams
from pydantic import BaseModel, ConfigDict, Field, model_validator


class FallParams(BaseModel):
    """Early termination on falls, shared by every task (PULSE code: contact and height 0.15 m)."""

    model_config = ConfigDict(extra="forbid")

    early_termination: bool = Field(
        True,
        description="terminate the episode when the humanoid falls ([P] and [CODE]: on)",
    )
    fall_height: float = Field(
        0.15,
        ge=0.0,
        description="a fall is a ground contact of any non-foot body OR the root origin lower than this above the "
        "ground, m (mocap.termination.fallen). [CODE] (ASE/PULSE compute_humanoid_reset) terminates on a "
        "non-foot contact AND a non-foot body below 0.15 m; 0 disables the height test",
    )
    allowed_contacts: tuple[str, ...] | None = Field(
        None,
        description="bodies allowed to touch the ground (default: the skeleton's feet, as the code's contact bodies)",
    )
    rule: Literal["contact_or_low_root", "contact_and_low_body"] = Field(
        "contact_or_low_root",
        description="'contact_or_low_root' = a non-foot ground contact OR the root below fall_height (this project's); "
        "'contact_and_low_body' = a non-foot contact AND some non-foot body below fall_height, not in an episode's first "
        "two control steps ([CODE] ASE/PULSE compute_humanoid_reset: fall_contact & fall_height, progress_buf > 1)",
    )


class StartParams(BaseModel):
    """Where an episode starts: the task protocol of the official PULSE code, or this project's
    (issue 65). Defaults: today's starts (any frame of any clip of the motion set, as sampled)."""

    model_config = ConfigDict(extra="forbid")

    clips: list[str] | None = Field(
        None,
        min_length=1,
        description="draw start frames from these clips only (default: every clip of the motion set, with its weight); "
        "[CODE] starts the speed, reach and strike commands at a random frame of the run clip (PULSE "
        "phc/data/cfg/env/env_pulse_amp.yaml:55, phc/env/tasks/humanoid_amp.py:358-367); [P] does not say",
    )
    face_x: bool = Field(
        False,
        description="turn each start about the vertical to face world +x ([CODE] speed: humanoid_speed.py turns the initial state to face +x)",
    )
    origin: bool = Field(False, description="move each start's root to x = y = 0 ([CODE] reach and strike move the root to the origin)")


class SpeedParams(BaseModel):
    """Parameters of the ``speed`` task (module docstring)."""

    model_config = ConfigDict(extra="forbid")

    seed: int = Field(
        0,
        description="seed of the task's torch.Generator (goal sampling); a factory `seed` argument overrides it",
    )
    speed_range: tuple[float, float] = Field(
        (0.0, 5.0),
        description="target speed v* ~ U[min, max], m/s ([P] and [CODE]: U[0, 5], about the fastest AMASS running)",
    )
    change_steps: tuple[int, int] = Field(
        (100, 200),
        description="the goal is resampled after U[min, max) control steps ([CODE] speedChangeStepsMin/Max 100, 200; "
        "[P] not stated); min = max: a fixed period",
    )
    direction: Literal["initial_heading", "world_x", "random"] = Field(
        "initial_heading",
        description="target direction d: 'initial_heading' = the root's facing at reset (equivalent to [CODE], which "
        "uses world +x and turns every initial state to face +x); 'world_x' = world +x ([CODE] literally; the env must "
        "face +x at reset for the same task); 'random' = uniform angle, resampled with the speed (ASE heading-style). "
        "[P]: 'target direction d_t', speed 'along x'",
    )
    velocity: Literal["root_lin_vel", "finite_difference"] = Field(
        "root_lin_vel",
        description="root velocity in the reward: 'root_lin_vel' = SimState.root_lin_vel ([P] 'the root velocity'); "
        "'finite_difference' = (root_pos - root_pos one control step earlier) / dt ([CODE] compute_speed_reward; "
        "needs the step() hook)",
    )
    scale: float = Field(
        0.25,
        gt=0.0,
        description="r = exp(-scale * (along-error^2 + tangent_weight * tangent^2)) ([CODE] vel_err_scale 0.25, ASE). "
        "[P] prints r = abs(v_t - v^0_t), which grows with the error (a typo), so the code's form is used",
    )
    tangent_weight: float = Field(
        0.1,
        ge=0.0,
        description="weight of the squared tangential speed ([CODE] tangent_err_w 0.1)",
    )
    start: StartParams = Field(default_factory=StartParams, description="where episodes start (StartParams: clips, face_x, origin)")
    termination: FallParams = Field(default_factory=FallParams, description="fall termination")

    @model_validator(mode="after")
    def _ranges(self) -> SpeedParams:
        if self.speed_range[0] > self.speed_range[1] or self.speed_range[0] < 0:
            raise ValueError(f"speed_range must be 0 <= min <= max, got {self.speed_range}")
        if self.change_steps[0] < 1 or self.change_steps[0] > self.change_steps[1]:
            raise ValueError(f"change_steps must be 1 <= min <= max, got {self.change_steps}")
        return self


class ReachParams(BaseModel):
    """Parameters of the ``reach`` task (module docstring)."""

    model_config = ConfigDict(extra="forbid")

    seed: int = Field(
        0,
        description="seed of the task's torch.Generator (target sampling); a factory `seed` argument overrides it",
    )
    body: str | None = Field(
        None,
        description="the reaching body (default: the right hand, R_Hand / right_hand) ([P] right hand)",
    )
    coefficient: float = Field(
        5.0,
        gt=0.0,
        description="r = exp(-coefficient * ||p_hand - c||^2): [P] 5 (App. C), [CODE] 4 (pos_err_scale)",
    )
    far_weight: float = Field(
        0.0,
        ge=0.0,
        le=1.0,
        description="r = (1 - w) exp(-coefficient d^2) + w exp(-far_coefficient d^2): weight w of a wide term that "
        "still rewards approaching a target metres away ([P] and [CODE]: 0, the narrow term only; ours)",
    )
    far_coefficient: float = Field(
        0.05,
        gt=0.0,
        description="coefficient of the wide term (far_weight): 0.05 pays 0.95 at 1 m, 0.29 at 5 m, 0.007 at 10 m "
        "(0.5 fell to ~0 at the 5 m a PULSE reach policy strays within 1M env steps; [DEFAULT], no paper has the term)",
    )
    mid_weight: float = Field(
        0.0,
        ge=0.0,
        le=1.0,
        description="weight m of a middle term: r = (1 - w - m) exp(-coefficient d^2) + m exp(-mid_coefficient d^2) "
        "+ w exp(-far_coefficient d^2), w = far_weight, w + m <= 1 ([P] and [CODE]: 0; ours)",
    )
    mid_coefficient: float = Field(
        1.0,
        gt=0.0,
        description="coefficient of the middle term (mid_weight): 1 pays 0.78 at 0.5 m, 0.37 at 1 m, 0.11 at 1.5 m, "
        "where exp(-5 d^2) is ~0 and exp(-0.05 d^2) is ~flat ([DEFAULT], no paper has the term)",
    )
    xy_range: float = Field(
        1.0,
        ge=0.0,
        description="target xy = anchor xy + U[-xy_range, xy_range]^2, m ([P] 2-m box: 1; [CODE] tarDistMax 1.0)",
    )
    height_range: tuple[float, float] = Field(
        (0.0, 2.0),
        description="target height U[min, max], m: [P] 2-m box centred at z = 1 -> (0, 2); [CODE] tarHeightMin/Max (0.2, 2.0)",
    )
    anchor: Literal["initial_root", "current_root"] = Field(
        "initial_root",
        description="centre of the sampling box: the root xy at the episode start ([CODE]: root xy zeroed at reset, "
        "targets sampled around the world origin, also when resampled mid-episode) or the root xy when sampling "
        "([P] 'within 1 meter of the humanoid')",
    )
    change_steps: tuple[int, int] = Field(
        (50, 100),
        description="a new target after U[min, max) control steps ([CODE] tarChangeStepsMin/Max 50, 100; [P] not stated)",
    )
    success_radius: float = Field(
        0.1,
        gt=0.0,
        description="a goal counts as reached within this hand-target distance, m (metrics only; [DEFAULT], not in the papers)",
    )
    start: StartParams = Field(default_factory=StartParams, description="where episodes start (StartParams: clips, face_x, origin)")
    termination: FallParams = Field(default_factory=FallParams, description="fall termination")

    @model_validator(mode="after")
    def _ranges(self) -> ReachParams:
        if self.height_range[0] > self.height_range[1]:
            raise ValueError(f"height_range must be min <= max, got {self.height_range}")
        if self.far_weight + self.mid_weight > 1.0 + 1e-9:
            raise ValueError(f"far_weight + mid_weight must be <= 1, got {self.far_weight} + {self.mid_weight}")
        if self.change_steps[0] < 1 or self.change_steps[0] > self.change_steps[1]:
            raise ValueError(f"change_steps must be 1 <= min <= max, got {self.change_steps}")
        return self


class StrikeParams(BaseModel):
    """Parameters of the ``strike`` task (module docstring)."""

    model_config = ConfigDict(extra="forbid")

    seed: int = Field(
        0,
        description="seed of the task's torch.Generator (box placement); a factory `seed` argument overrides it",
    )
    reward: Literal["code", "paper"] = Field(
        "code",
        description="'paper' = [P] r = 1 - u_up . u_t in [0, 2] (max_reward 2); 'code' = [CODE] 0.6 max(0, 1 - u_up . u_t) "
        "+ 0.4 r_vel, and 1 once u_up . u_t < success_up_dot, in [0, 1]",
    )
    rot_weight: float = Field(
        0.6,
        ge=0.0,
        description="code reward: weight of the tilt term ([CODE] tar_rot_w 0.6)",
    )
    vel_weight: float = Field(
        0.4,
        ge=0.0,
        description="code reward: weight of the approach term ([CODE] vel_reward_w 0.4)",
    )
    toward_speed: float = Field(
        1.0,
        gt=0.0,
        description="code reward: target approach speed, m/s ([CODE] tar_speed 1.0)",
    )
    vel_scale: float = Field(
        4.0,
        gt=0.0,
        description="code reward: r_vel = exp(-vel_scale * max(0, toward_speed - v)^2) ([CODE] 4.0)",
    )
    success_up_dot: float = Field(
        0.2,
        ge=-1.0,
        le=1.0,
        description="the box is knocked over when u_up . u_t < this ([CODE] succ: tar_rot_err < 0.2); code reward 1 then",
    )
    velocity: Literal["root_lin_vel", "finite_difference"] = Field(
        "finite_difference",
        description="root velocity of the code reward: SimState.root_lin_vel, or (root_pos - previous root_pos) / dt "
        "([CODE] compute_strike_reward; needs the step() hook)",
    )
    distance: tuple[float, float] = Field(
        (1.5, 5.0),
        description="box distance from the root U[min, max], m ([P] 1.5-5 m; [CODE] tar_dist_min/max 0.5, 10)",
    )
    near_prob: float = Field(
        0.0,
        ge=0.0,
        le=1.0,
        description="probability of a 'near' box at U[distance[0], near_max] ([P] none: 0; [CODE] near_prob 0.5)",
    )
    near_max: float = Field(
        1.5,
        gt=0.0,
        description="maximum distance of a 'near' box, m ([CODE] near_dist 1.5)",
    )
    random_yaw: bool = Field(True, description="uniform yaw of the box at reset ([CODE] yes; [P] not stated)")
    half_size: tuple[float, float, float] = Field(
        (0.2, 0.2, 0.9),
        description="box half extents, m; it stands with its centre at half_size[2] ([CODE] centre height 0.9 m; the horizontal size is [DEFAULT])",
    )
    density: float = Field(30.0, gt=0.0, description="box density, kg/m^3 ([CODE] asset density 30)")
    friction: float = Field(0.9, gt=0.0, description="box friction coefficient ([DEFAULT], the simulator's)")
    strike_bodies: tuple[str, ...] | None = Field(
        None,
        description="bodies allowed to touch the box: default the right hand only ([P] 'any body other than the right "
        "hand'); [CODE] strikeBodyNames R_Hand, R_Wrist, R_Elbow (smpl; right_hand, right_lower_arm on amp)",
    )
    illegal_contact: Literal["paper", "code", "off"] = Field(
        "paper",
        description="terminate on a forbidden box contact: 'paper' = any non-strike body touches the box ([P]); 'code' = "
        "a non-strike, non-foot body touching it with a contact-force component > contact_force_threshold ([CODE]); 'off'",
    )
    contact_force_threshold: float = Field(50.0, ge=0.0, description="contact force for the 'code' rule, N ([CODE] 50)")
    sixd: Literal["zhou", "tan_norm"] = Field(
        "tan_norm",
        description="6-D rotation of the box orientation ([CODE] quat_to_tan_norm; [P] unspecified)",
    )
    start: StartParams = Field(default_factory=StartParams, description="where episodes start (StartParams: clips, face_x, origin)")
    termination: FallParams = Field(
        default_factory=FallParams,
        description="fall termination (ground contacts only)",
    )

    @model_validator(mode="after")
    def _ranges(self) -> StrikeParams:
        if not 0.0 < self.distance[0] <= self.distance[1]:
            raise ValueError(f"distance must be 0 < min <= max, got {self.distance}")
        if self.near_prob > 0 and self.near_max < self.distance[0]:
            raise ValueError(f"near_max ({self.near_max}) must be >= distance[0] ({self.distance[0]})")
        return self


class TerrainTaskParams(BaseModel):
    """Parameters of the ``terrain`` task (module docstring)."""

    model_config = ConfigDict(extra="forbid")

    seed: int = Field(0, description="seed of the task's torch.Generator (trajectories, spawn points); a factory `seed` overrides it")
    terrain: TerrainParams = Field(
        default_factory=lambda: TerrainParams(kind="stairs", size=20.0),
        description="the simulator's height field (sim_overrides): kind flat / rough / stairs / slopes / obstacles; "
        "[CODE] PACER maps are 20 x 20 m per terrain",
    )
    episode_steps: int = Field(300, ge=2, description="episode length, control steps ([CODE] PULSE 300 = 10 s)")
    spawn_radius: float = Field(0.5, ge=0.0, description="roots start uniformly in [-r, r]^2 around the origin, m (<= terrain.flat_radius)")
    num_verts: int = Field(101, ge=2, description="trajectory vertices over the episode ([CODE] PACER 101)")
    speed_range: tuple[float, float] = Field((0.0, 3.0), description="trajectory speed range, m/s ([P] [0, 3])")
    accel_max: float = Field(2.0, ge=0.0, description="maximum |speed change| per second, m/s^2 ([P] 2)")
    dtheta_max: float = Field(2.0, ge=0.0, description="maximum heading change per second outside sharp turns, rad/s ([CODE] 2.0)")
    sharp_turn_prob: float = Field(0.02, ge=0.0, le=1.0, description="probability of a sharp turn U[-pi, pi] per segment ([CODE] 0.02)")
    bounds_margin: float = Field(1.0, ge=0.0, description="vertices are clamped this far inside the terrain square, m")
    num_samples: int = Field(10, ge=1, description="trajectory samples in the observation ([P] [CODE] 10)")
    sample_spacing: float = Field(0.5, gt=0.0, description="time between observed samples, s ([CODE] 0.5: a 5-s horizon)")
    map_shape: tuple[int, int] = Field((32, 32), description="height-map grid H x W ([P] 32 x 32)")
    map_size: float = Field(2.0, gt=0.0, description="side of the height-map square, m ([P] 2 m)")
    distance: Literal["paper", "code"] = Field(
        "paper", description="tracking error e: 'paper' = ||p - tau|| ([P] exp(-2 ||.||)); 'code' = ||p - tau||^2 ([CODE] PACER)"
    )
    pos_scale: float = Field(2.0, gt=0.0, description="r_track = exp(-pos_scale e) ([P] [CODE] 2)")
    energy_weight: float = Field(0.0005, ge=0.0, description="energy coefficient ([P] 0.0005; 0 disables)")
    energy_form: Literal["paper", "code"] = Field(
        "code",
        description="'paper' = -c sum (tau qdot)^2 ([P]); 'code' = -c sum |tau qdot| ([CODE] PHC power reward, zero for the "
        "first 3 steps; default: the squared form measured ~-1e2 per step on a falling amp humanoid, dwarfing the (0, 1] "
        "tracking term)",
    )
    fail_distance: float | None = Field(4.0, gt=0.0, description="terminate when the root is farther from tau(t), m ([DEFAULT]; None: never)")
    termination: FallParams = Field(default_factory=FallParams, description="fall termination")

    @model_validator(mode="after")
    def _ranges(self) -> TerrainTaskParams:
        lo, hi = self.speed_range
        if not 0.0 <= lo <= hi:
            raise ValueError(f"speed_range must be 0 <= min <= max, got {self.speed_range}")
        if min(self.map_shape) < 1:
            raise ValueError(f"map_shape must be positive, got {self.map_shape}")
        if self.bounds_margin >= self.terrain.size:
            raise ValueError(f"bounds_margin ({self.bounds_margin}) must be smaller than terrain.size ({self.terrain.size})")
        return self


class PointGoalParams(BaseModel):
    """Parameters of the ``point_goal`` task (module docstring)."""

    model_config = ConfigDict(extra="forbid")

    seed: int = Field(0, description="seed of the task's torch.Generator (targets); a factory `seed` argument overrides it")
    radius: float = Field(10.0, gt=0.0, description="targets uniform in the disc of this radius around the start xy, m ([P] 10 m)")
    change_steps: int = Field(120, ge=1, description="a new target every this many control steps ([P] 4 s = 120 at 30 Hz)")
    episode_steps: int = Field(240, ge=1, description="episode length, control steps ([P] at most 8 s = 240)")
    pos_weight: float = Field(0.7, ge=0.0, description="weight of r_pos ([P] Eq. 16: 0.7)")
    speed_weight: float = Field(0.3, ge=0.0, description="weight of r_speed ([P] Eq. 16: 0.3)")
    pos_scale: float = Field(0.5, gt=0.0, description="r_pos = exp(-pos_scale ||p - t||^2) ([P] 0.5)")
    target_speed: float = Field(1.0, ge=0.0, description="u in r_speed = exp(-max(0, u - <v, d>)^2), m/s ([P] 1)")
    direction: Literal["toward_target", "paper"] = Field(
        "toward_target",
        description="d in r_speed: 'toward_target' = (t - p) / ||t - p|| (our fix of Eq. 16's sign); 'paper' = (p - t) / ||p - t|| "
        "as printed, pointing away from the target",
    )
    arrive_radius: float = Field(
        0.5, ge=0.0, description="r = 1 within this ground distance of the target, m ([P] 'maximum value once arrived'; radius [DEFAULT])"
    )
    termination: Literal["paper", "fall", "both"] = Field(
        "paper", description="'paper' = head below head_height ([P]); 'fall' = the shared fall test (fall params); 'both'"
    )
    head_height: float = Field(0.5, ge=0.0, description="paper termination: head origin below this height, m ([P] 0.5)")
    head: str | None = Field(None, description="the head body (default: head / Head)")
    fall: FallParams = Field(default_factory=FallParams, description="the shared fall test (termination 'fall' / 'both')")

    @model_validator(mode="after")
    def _weights(self) -> PointGoalParams:
        if self.pos_weight + self.speed_weight <= 0:
            raise ValueError("pos_weight + speed_weight must be > 0")
        return self


class InbetweenParams(BaseModel):
    """Parameters of the ``inbetween`` task (module docstring)."""

    model_config = ConfigDict(extra="forbid")

    seed: int = Field(0, description="seed of the task's torch.Generator (keyframe times); a factory `seed` overrides it")
    sequence_steps: int = Field(120, ge=2, description="window length = episode length, control steps ([P] 4 s = 120)")
    num_keyframes: int = Field(5, ge=2, description="keyframes including the window's first and last frame ([DEFAULT] 5; [P] 4 or 5)")
    keyframe: Literal["full_body", "root"] = Field("full_body", description="keyframe content: every body ([P]) or the root only")
    time_encoding: Literal["add", "concat"] = Field("add", description="time-to-arrival encoding added to g_hat ([P] as printed) or appended")
    time_encoding_dim: int = Field(16, ge=2, description="'concat': encoding size (even)")
    reward_target: Literal["trajectory", "keyframes"] = Field(
        "trajectory", description="'trajectory' = Eq. 14 against the ground truth at every step ([P]); 'keyframes' = against each keyframe at its step only"
    )
    weights: tuple[float, float, float, float] = Field((0.1, 0.65, 0.1, 0.15), description="r_root, r_q, r_alpha, r_ee weights ([P] Eq. 14)")
    scales: tuple[float, float, float, float] = Field((10.0, 2.0, 0.5, 40.0), description="kernel scales of r_root, r_q, r_alpha, r_ee ([P] Eq. 10)")
    end_effectors: tuple[str, ...] | None = Field(None, description="r_ee bodies (default: names containing 'hand' or 'foot')")
    termination: Literal["paper", "fall", "both"] = Field("paper", description="'paper' = ground-truth distance ([P]); 'fall'; 'both'")
    termination_distance: float = Field(0.5, gt=0.0, description="paper termination distance, m ([P] 0.5)")
    distance_reduce: Literal["max", "mean"] = Field("max", description="'max' = any body ([P]); 'mean' = mean over bodies (PHC/UHC)")
    success_radius: float = Field(0.2, gt=0.0, description="a keyframe is hit within this mean body error, m ([DEFAULT]; not in the paper)")
    fall: FallParams = Field(default_factory=FallParams, description="the shared fall test (termination 'fall' / 'both')")

    @model_validator(mode="after")
    def _ranges(self) -> InbetweenParams:
        if self.num_keyframes > self.sequence_steps + 1:
            raise ValueError(f"num_keyframes ({self.num_keyframes}) must be <= sequence_steps + 1 ({self.sequence_steps + 1})")
        if sum(self.weights) <= 0 or min(self.weights) < 0:
            raise ValueError(f"weights must be >= 0 with a positive sum, got {self.weights}")
        if self.time_encoding_dim % 2:
            raise ValueError("time_encoding_dim must be even")
        return self


class GenerationTaskParams(BaseModel):
    """Parameters of the ``generation`` task (module docstring)."""

    model_config = ConfigDict(extra="forbid")

    seed: int = Field(0, description="seed of the task's torch.Generator (unused: the prior noise uses the env's)")
    noise_scale: float = Field(1.0, ge=0.0, description="prior noise scale (PULSE: sigma_p multiplier; 0 = prior mean)")
    episode_steps: int = Field(300, ge=1, description="rollout length, control steps (10 s; hybrid-RVQ evaluates 30 s = 900)")
    fall_height: float = Field(0.15, gt=0.0, description="fall metric: a non-foot body touching the ground below this, m ([CODE] PULSE 0.15)")
    diversity_steps: int | None = Field(None, ge=1, description="horizon of the diversity trajectories, steps (default: episode_steps)")
    diversity_stride: int = Field(5, ge=1, description="record body positions every this many steps (6 Hz at 5)")
    diversity_rollouts: int = Field(64, ge=2, description="at most this many trajectories per metrics() call (pairs grow quadratically)")
    fall: FallParams = Field(
        default_factory=lambda: FallParams(early_termination=False),
        description="termination (default off: rollouts continue after a fall, as mocap.generation)",
    )

    @model_validator(mode="after")
    def _horizon(self) -> GenerationTaskParams:
        if self.diversity_steps is not None and self.diversity_steps > self.episode_steps:
            raise ValueError(f"diversity_steps ({self.diversity_steps}) must be <= episode_steps ({self.episode_steps})")
        return self
