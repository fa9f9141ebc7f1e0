"""The roles a plugin can fill: simulator, imitator, latent space, task, trainer, metric, motion source.

These abstract classes fix what every implementation exchanges (tensors, shapes, frames) so that
any latent space composes with any task and any simulator. The data types live in
:mod:`mocap.state`; conventions (z up, wxyz, SI, heading frame) are documented there.

How the three latent families fit :class:`LatentSpace`:

============  ==========================================  ======================  ==========================
family        ``encode(obs)`` conditions on               ``prior(obs)``          ``task_action_space``
============  ==========================================  ======================  ==========================
PULSE         proprio + imitation goal (Gaussian)         learned Gaussian R(z|s)  continuous residual (Box)
VMP           ``obs.extra["window"]``: 2W+1 kinematic      N(0, I), ignores s      continuous latent (Box)
              frames (Gaussian)
Hybrid-RVQ    proprio + imitation goal; quantized margin  deterministic z_p = f(s) code indices per
              over the prior (``LatentSample.indices``)   (``std`` is ``None``)   codebook (MultiDiscrete)
============  ==========================================  ======================  ==========================
"""

from __future__ import annotations

from abc import ABC, abstractmethod
from dataclasses import dataclass, field
from pathlib import Path
from types import MappingProxyType
from typing import TYPE_CHECKING, Any, Callable, ClassVar, Mapping, Protocol, Sequence, runtime_checkable

import numpy as np
import torch
from torch import Tensor

from mocap.roles import ActionSpace, Box, MotionSource, MultiDiscrete
from mocap.skeleton import Skeleton
from mocap.state import HumanoidState, MotionFrames, Observations, SimState, TargetState, Trajectories

if TYPE_CHECKING:  # pragma: no cover
    from mocap.observations import SixD
    from mocap.pipeline import StageContext


# ----------------------------------------------------------------------------------- simulator
class Simulator(ABC):
    """``num_envs`` humanoids of one :class:`Skeleton`, stepped together at the control rate.

    Actions are PD targets: (N, D) hinge angles in rad, skeleton DoF order; the PD loop runs
    inside the simulator at the physics rate (``dt / substeps``).
    """

    skeleton: Skeleton
    num_envs: int
    #: where :attr:`state`'s tensors live (a :class:`torch.device`; the MuJoCo simulator: the CPU)
    device: torch.device = torch.device("cpu")

    @property
    @abstractmethod
    def dt(self) -> float:
        """Control period in seconds (1/30 by default)."""

    @property
    @abstractmethod
    def state(self) -> SimState:
        """The current batched state (see :class:`mocap.state.SimState`)."""

    @abstractmethod
    def reset(self, env_ids: Tensor, state: HumanoidState) -> None:
        """Set envs ``env_ids`` (K,) to ``state`` (K rows; root, dofs and their velocities are used)."""

    @abstractmethod
    def step(self, actions: Tensor) -> SimState:
        """Advance every env by one control step with PD targets ``actions`` (N, D); return the state."""

    @property
    def instability_count(self) -> int:
        """Number of env resets caused by numerical instability since construction."""
        return 0

    def close(self) -> None:  # noqa: B027 - optional hook
        """Release native resources."""

    # ------------------------------------------------------------- optional capabilities
    # What envs, tasks and commands use when a simulator offers it; each default says "not offered".
    @property
    def ground_contact(self) -> Tensor | None:
        """(N, B) bool contacts with the ground only (not props), or None: callers then use
        ``SimState.body_contact`` (fall detection that a struck prop must not trigger)."""
        return None

    def height_at(self, xy: Tensor) -> Tensor:
        """Ground height (...) at world ``xy`` (..., 2), m. Default: the plane z = 0."""
        return torch.zeros(xy.shape[:-1], dtype=xy.dtype, device=xy.device)

    def get_physics_state(self) -> np.ndarray | None:
        """(N, S) float64 copy of every env's full physics state, for bit-exact save and resume; None
        when the simulator has none (envs then save the :class:`SimState` fields and restore them
        with :meth:`reset`)."""
        return None

    def set_physics_state(self, env_ids: Tensor, states: np.ndarray, *, as_reset: bool = True) -> None:
        """Write states from :meth:`get_physics_state` into envs ``env_ids`` (only called when
        :meth:`get_physics_state` returned one)."""
        raise NotImplementedError(f"{type(self).__name__} has no physics state to set")

    def make_recorder(self, *, ghost: bool = False, **options: Any) -> Any | None:
        """A video recorder of env 0 (``add_frame(sim, ...)``, ``save(path)``; the MuJoCo simulator's is
        ``mocap_sim_mujoco.render``), with a reference ghost when ``ghost``; None when the simulator
        cannot render."""
        return None


# ------------------------------------------------------------------------------------ imitator
class Imitator(ABC):
    """A motion-imitation policy: proprioception + imitation goal -> PD targets.

    A trained imitator (PHC/PHC+) is the teacher that latent spaces distill from. A policy-based
    imitator separates its raw policy output (``policy_output``, e.g. PHC's normalized action or
    residual) from the mapping to PD targets (``to_pd_targets``), so that a student (a latent
    space's decoder) can learn the raw output and reuse the teacher's mapping.
    """

    @abstractmethod
    def act(self, obs: Observations, deterministic: bool = True) -> Tensor:
        """(N, D) PD targets, rad, from ``obs.proprio`` (N, P) and ``obs.goal`` (N, G)."""

    def policy_output(self, obs: Observations, deterministic: bool = True) -> Tensor:
        """(N, A) the raw policy output before the PD-target mapping (default: the PD targets)."""
        return self.act(obs, deterministic)

    def to_pd_targets(self, obs: Observations, output: Tensor) -> Tensor:
        """Map a raw output (N, A) to PD targets (N, D) (default: identity)."""
        return output

    @abstractmethod
    def observe(self, state: SimState, reference: MotionFrames) -> Observations:
        """Build the imitator's observation from the simulated state and the next reference frames
        (with ``reference.ahead`` holding the later ones when :attr:`reference_steps` > 1)."""

    #: how many reference frames ``observe`` reads: the next control step's (t + 1) and
    #: ``reference_steps - 1`` later ones in ``reference.ahead``. Whoever drives an imitator builds
    #: its reference with :meth:`mocap.motion.library.MotionLibrary.frames_ahead` (a distillation
    #: refuses a teacher with more than one: latent encoders observe one goal frame).
    reference_steps: int = 1

    #: the trained policy network (a :class:`mocap.rl.networks.ActorCritic`) when the imitator has
    #: one: students distilled from it may copy its input statistics (``policy.obs_norm``)
    policy: Any = None

    @property
    def proprio_sixd(self) -> SixD:
        """The 6D-rotation layout of the imitator's proprioception (:func:`mocap.observations.proprioception`),
        which a latent space driving it must use too. Default ``"zhou"``."""
        return "zhou"


# -------------------------------------------------------------------------------- latent space
@dataclass
class LatentSample:
    """A latent distribution over ``z`` (N, Z) and, for quantized families, the chosen codes.

    Attributes:
        mean: (N, Z) mean (or the deterministic value).
        std: (N, Z) standard deviation, or ``None`` for a deterministic latent.
        z: (N, Z) the sample the decoder receives (the mean when not sampling).
        indices: (N, M) long code indices per quantizer level (quantized families), else ``None``.
        losses: named scalar losses produced on the way (KL, commitment, ...).
    """

    mean: Tensor
    std: Tensor | None = None
    z: Tensor | None = None
    indices: Tensor | None = None
    losses: dict[str, Tensor] = field(default_factory=dict)


class LatentSpace(torch.nn.Module, ABC):
    """A motion representation: encoder, decoder, prior, and how a task policy acts in it."""

    latent_dim: int

    @abstractmethod
    def encoder(self, obs: Observations) -> LatentSample:
        """Posterior over z given what the family conditions on (see the module table)."""

    @abstractmethod
    def decoder(self, obs: Observations, z: Tensor) -> Tensor:
        """(N, D) PD targets from proprioception ``obs.proprio`` and latent ``z`` (N, Z)."""

    @abstractmethod
    def prior(self, obs: Observations) -> LatentSample:
        """Prior over z given proprioception (N(0, I), learned Gaussian, or deterministic)."""

    @property
    @abstractmethod
    def task_action_space(self) -> ActionSpace:
        """The space a downstream task policy acts in."""

    @abstractmethod
    def to_latent(self, obs: Observations, task_action: Tensor) -> Tensor:
        """Map a task action (residual, absolute latent or code indices) to z (N, Z)."""

    @property
    def config(self) -> dict[str, Any] | None:
        """The architecture as plain values, saved next to the weights in ``latent.pt`` and compared
        with the spec when a checkpoint is loaded (a property: a method would be pickled). Default None."""
        return None

    # ------------------------------------------------ optional: what tasks, generation and eval use
    #: the latent space has an encoder (a posterior over z); False for the ``scratch`` baseline, whose
    #: task action is the PD target itself: the framework then never calls :meth:`encoder`, and
    #: imitating through it (``LatentImitator``, ``mocap eval``) is refused with a clear error
    has_encoder: bool = True
    #: the latent space has a prior that :meth:`random_action` samples (random generation, the
    #: ``generation`` task, ``mocap generate``); False for the no-latent ``scratch`` baseline
    samples_prior: ClassVar[bool] = False

    @property
    def decodes_pd_targets(self) -> bool:
        """True when :meth:`decode_action` and :meth:`random_action` give PD targets themselves (VMP's
        tracker); False: they give the teacher's raw policy output, mapped by the imitator."""
        return False

    def decode_action(self, obs: Observations, z: Tensor) -> Tensor:
        """The raw action for ``z`` (N, Z): what a task env steps with after the imitator's mapping
        (PULSE: the teacher's raw output). Default: :meth:`decoder`."""
        return self.decoder(obs, z)

    def random_action(self, obs: Observations, noise_scale: float = 1.0, generator: torch.Generator | None = None) -> Tensor:
        """One step of unconditional generation: a prior sample decoded like :meth:`decode_action`
        (only when :attr:`samples_prior`)."""
        raise NotImplementedError(f"{type(self).__name__} has no prior to sample")

    def as_imitator(self, library: Any, dt: float | None = None, device: Any = "cpu") -> Imitator | None:
        """The latent space's own tracking policy as an :class:`Imitator` over ``library`` (VMP's
        stage 2: ``mocap eval`` then evaluates it without a teacher), or None (default)."""
        return None

    def attach_imitator(self, imitator: Imitator) -> "LatentSpace":
        """Use ``imitator`` (the teacher) to map decoder outputs to PD targets; returns ``self``."""
        return self

    def reset_envs(self, env_ids: Tensor) -> None:  # noqa: B027 - optional hook
        """Envs ``env_ids`` of a task env were reset (latents with per-env state: VMP's action history)."""

    # optional hooks of the shared ``distill`` trainer (a student also implements DistillableLatent)
    def init_from_teacher(self, teacher: Imitator) -> None:  # noqa: B027 - optional hook
        """Called once before distillation starts (e.g. copy the teacher policy's input statistics);
        a ValueError is reported as a spec mismatch."""

    def update_normalizers(self, obs: Observations) -> None:  # noqa: B027 - optional hook
        """Fold a rollout chunk's observations (fields (T, N, ...)) into the student's running
        statistics, before each update (data-parallel: merged over ranks)."""

    def rl_hook(self) -> Any | None:
        """An on-policy RL term added to distillation (PULSE's Table 3 ablation), or None."""
        return None

    def task_state_dict(self) -> dict[str, Any]:
        """Per-env state kept while driving a task env (for bit-exact resume)."""
        return {}

    def load_task_state_dict(self, state: dict[str, Any]) -> None:  # noqa: B027 - optional hook
        """Restore :meth:`task_state_dict`."""


# ----------------------------------------------------------------- optional simulator capabilities
# What a task or a trainer may ask of a simulator beyond :class:`Simulator`, declared so that a
# simulator author sees the contract and the framework checks it with ``isinstance`` (never by
# probing attribute names). ``mocap.testing.check_simulator`` exercises each one a simulator offers.
@runtime_checkable
class MovableTarget(Protocol):
    """A target prop per env that a task places and reads (the ``strike`` task's box). ``has_target``
    is False for a simulator of this kind built without the prop (its ``set_target`` then raises)."""

    @property
    def has_target(self) -> bool: ...

    def set_target(self, env_ids: Tensor, pos: Tensor, rot: Tensor | None = None) -> None:
        """Place the props of envs ``env_ids`` (K,) at ``pos`` (K, 3), ``rot`` (K, 4) wxyz (default
        upright), at rest; part of those envs' reset state from then on."""
        ...

    def target_state(self) -> TargetState:
        """Every env's prop: :class:`mocap.state.TargetState` (N rows)."""
        ...


@runtime_checkable
class ExternalWrench(Protocol):
    """External forces and torques held on the bodies (VMP's pushes)."""

    def set_external_wrench(self, env_ids: Tensor, wrench: Tensor) -> None:
        """Hold ``wrench`` (K, B, 6): force (N) then torque (N m), world frame, per skeleton body, on
        envs ``env_ids`` (K,) until changed or the env is reset."""
        ...


@runtime_checkable
class PerEnvModels(Protocol):
    """Per-env physical models that may be edited between steps (VMP's mass and friction randomization)."""

    def env_models(self) -> list[Any]:
        """N models (MuJoCo ``MjModel``), one per env, independent of each other."""
        ...


@runtime_checkable
class DistillableLatent(Protocol):
    """What the shared ``distill`` trainer needs from a latent space (PULSE, Hybrid-RVQ, ...).

    The student sees the teacher's observation (``Observations``: proprio + imitation goal) and
    learns the teacher's raw policy output (:meth:`Imitator.policy_output`); the simulator is
    stepped with ``teacher.to_pd_targets(obs, student_action(obs))``.
    """

    def student_action(self, obs: Observations, sample: bool = True) -> Tensor:
        """(N, A) the student's action: z from the encoder (sampled, or its mean), decoder mean."""
        ...

    def distill_losses(self, obs: Observations, teacher_output: Tensor, starts: Tensor, progress: float) -> dict[str, Tensor]:
        """Losses on a (T, N) rollout chunk in time order (``obs`` fields are (T, N, ...)).

        ``teacher_output`` (T, N, A); ``starts`` (T, N) bool marks the first step of an episode
        (temporal terms must not cross it); ``progress`` in [0, 1] drives schedules (e.g. the KL
        weight). Returns named scalars including ``"loss"``, the total to minimize.
        """
        ...


@runtime_checkable
class RLTrainable(Protocol):
    """A stage component that PPO (or another RL trainer) can train: it builds its own RL problem.

    The PHC imitator and VMP's tracker implement it; a trainer gets the env through
    ``ctx.make_rl_env(num_envs)`` (:class:`mocap.pipeline.StageContext`), which calls this.
    """

    def make_env(self, ctx: Any, num_envs: int) -> Any:
        """A :class:`mocap.rl.env.VecEnv` of ``num_envs`` envs for the stage ``ctx``."""
        ...


# ---------------------------------------------------------------------------------------- task
class Task(ABC):
    """A downstream objective. It never knows which latent space (if any) drives the humanoid."""

    goal_dim: int

    @abstractmethod
    def reset(self, env_ids: Tensor, state: SimState) -> None:
        """Sample new goals for envs ``env_ids`` (K,) after they were reset. ``state`` is the whole
        batch after the reset (N rows, the task env passes the simulator's state): read rows
        ``state.index(env_ids)``."""

    @abstractmethod
    def observe(self, state: SimState) -> Tensor:
        """(N, goal_dim) goal observation, expressed in each humanoid's heading frame."""

    @abstractmethod
    def reward(self, state: SimState, actions: Tensor) -> Tensor:
        """(N,) reward for the transition that produced ``state``."""

    @abstractmethod
    def terminated(self, state: SimState) -> Tensor:
        """(N,) bool: the episode failed (not a time-limit truncation)."""

    def metrics(self) -> dict[str, float]:
        """Task metrics accumulated since the last call (documented per task)."""
        return {}

    # ------------------------------------------------ optional: what the task env reads and calls
    #: control steps before a time-limit truncation
    episode_steps: int = 300
    #: the largest per-step reward (``normalized_return = return / (max_reward × episode_steps)``)
    max_reward: float = 1.0
    #: the generation task: the task action is ignored and the latent prior is rolled out
    #: (``LatentSpace.random_action`` with ``prior_noise_scale``)
    prior_rollout: bool = False
    prior_noise_scale: float = 1.0
    #: the task follows the clip it started from: the env calls :meth:`reference_start` and starts
    #: episodes on the control grid (reference read from the precomputed table)
    tracks_reference: bool = False
    #: simulator options the task needs (a target prop, a terrain), merged into the simulator's params
    sim_overrides: Mapping[str, Any] = MappingProxyType({})
    #: the clips the task env draws start frames from (None: every clip of the motion set, with its weight)
    start_clips: Sequence[str] | None = None

    def attach(self, sim: "Simulator") -> None:  # noqa: B027 - optional hook
        """Called once with the simulator the task runs in (props, ground contacts, terrain)."""

    def attach_motions(self, library: Any) -> None:  # noqa: B027 - optional hook
        """Called once with the motion library (a :class:`mocap.motion.library.MotionLibrary`)."""

    def start_state(self, env_ids: Tensor, frames: MotionFrames) -> HumanoidState:
        """The start states of envs ``env_ids`` given the sampled reference ``frames`` (terrain spawn,
        keyframe sequences); a :class:`MotionFrames` result also says which clip and time were
        chosen. Default: the frames as sampled."""
        return frames

    def reference_start(self, env_ids: Tensor, clip_ids: Tensor, times: Tensor) -> None:  # noqa: B027
        """Envs ``env_ids`` start at ``times`` (s) of clips ``clip_ids`` (tasks with ``tracks_reference``)."""

    def step(self, state: SimState) -> None:  # noqa: B027 - optional hook
        """Called after every simulator step, after :meth:`reward` (advance per-env task state)."""

    def truncated(self, state: SimState) -> Tensor | None:
        """(N,) bool: episodes the task ends without failure (a tracked clip ran out); None: none."""
        return None

    def state_dict(self) -> dict[str, Any]:
        """Per-env task state for bit-exact resume (tensors, plain values)."""
        return {}

    def markers(self, env_id: int = 0) -> list[tuple[Any, tuple[float, ...], float]] | None:
        """Goal markers of env ``env_id`` drawn in task videos: ``[(position (3,), rgba, radius)]``,
        or None (default: none)."""
        return None

    def load_state_dict(self, state: dict[str, Any]) -> None:  # noqa: B027 - optional hook
        """Restore :meth:`state_dict`."""


# ------------------------------------------------------------------------------------- metrics
class Metric(ABC):
    """A named measurement of simulated vs reference trajectories (:class:`mocap.state.Trajectories`).

    Returns a per-episode (N,) tensor in :attr:`unit` (see :mod:`mocap.metrics` for definitions).
    """

    name: str
    unit: str

    @abstractmethod
    def __call__(self, tr: Trajectories) -> Tensor: ...


# ------------------------------------------------------------------------------------ trainers
@dataclass
class StageResult:
    """What a stage leaves behind: its checkpoint file and summary metrics."""

    checkpoint: Path | None
    metrics: dict[str, float] = field(default_factory=dict)


class Trainer(ABC):
    """Runs one pipeline stage (``imitator``, ``latent``, ``task`` or ``eval``).

    A trainer owns its checkpoints (in ``ctx.workdir``), logging (``ctx.log``) and resume: when it
    finds a checkpoint of an unfinished run in ``ctx.workdir`` it continues from it. It must
    check ``ctx.should_stop()`` between iterations and, when it returns True, save and return.
    """

    #: True when the trainer runs on every rank under torchrun (data-parallel); False: rank 0 runs
    #: it alone while the other ranks wait (:mod:`mocap.distributed`)
    data_parallel: ClassVar[bool] = False

    @abstractmethod
    def run(self, ctx: "StageContext") -> StageResult: ...

    def preflight(self, resolved: Any, plugins: Any) -> None:  # noqa: B027 - optional hook
        """Checks that need no training, run by ``mocap run`` before its first stage trains (a clip
        name, an input file), so that a mistake is reported in seconds instead of after hours of
        training. ``resolved``: the validated spec (:class:`mocap.spec.ResolvedSpec`); ``plugins``:
        the registry. Raise :class:`mocap.errors.UserError` with one line naming the field. Default:
        nothing to check."""


Factory = Callable[..., Any]
__all__: Sequence[str] = (
    "ActionSpace",
    "Box",
    "DistillableLatent",
    "ExternalWrench",
    "Imitator",
    "LatentSample",
    "LatentSpace",
    "Metric",
    "MotionSource",
    "MovableTarget",
    "MultiDiscrete",
    "PerEnvModels",
    "RLTrainable",
    "Simulator",
    "StageResult",
    "Task",
    "Trainer",
)
