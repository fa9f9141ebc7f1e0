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
from typing import TYPE_CHECKING, Any, Callable, ClassVar, Protocol, Sequence

import torch
from torch import Tensor

from mocap.skeleton import Skeleton
from mocap.state import HumanoidState, MotionFrames, Observations, SimState, Trajectories

if TYPE_CHECKING:  # pragma: no cover
    from mocap.pipeline import StageContext


# --------------------------------------------------------------------------------------- spaces
@dataclass(frozen=True)
class Box:
    """A continuous action space of ``shape`` with elementwise bounds (``inf`` for unbounded).

    ``exploration_sigma``: the exploration σ the space's method prescribes for a Gaussian policy on
    it (PULSE Sec. 3.3: a fixed 0.22 on the prior residual), used by PPO when the spec leaves
    ``log_std_init`` unset; None: no prescription.
    """

    shape: tuple[int, ...]
    low: float = float("-inf")
    high: float = float("inf")
    exploration_sigma: float | None = None


@dataclass(frozen=True)
class MultiDiscrete:
    """One categorical choice per entry of ``nvec`` (e.g. a code index per RVQ codebook)."""

    nvec: tuple[int, ...]


ActionSpace = Box | MultiDiscrete


# ----------------------------------------------------------------------------------- simulator
class Simulator(ABC):
    """``num_envs`` humanoids of one :class:`Skeleton`, stepped together at the control rate.

    Actions are PD targets: (N, D) hinge angles in rad, skeleton DoF order; the PD loop runs
    inside the simulator at the physics rate (``dt / substeps``).
    """

    skeleton: Skeleton
    num_envs: int

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
        """Build the imitator's observation from the simulated state and the next reference frames."""


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


# ---------------------------------------------------------------------------------------- task
class Task(ABC):
    """A downstream objective. It never knows which latent space (if any) drives the humanoid."""

    goal_dim: int

    @abstractmethod
    def reset(self, env_ids: Tensor, state: SimState) -> None:
        """Sample new goals for envs ``env_ids`` after they were reset to ``state``."""

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


# --------------------------------------------------------------------------------- motion data
class MotionSource(ABC):
    """Loads clips from some format and converts them to :class:`mocap.motion.clip.Clip`."""

    @abstractmethod
    def load(self, skeleton: Skeleton) -> Any:
        """Return a ``MotionSet`` of clips on ``skeleton`` (bad files skipped and listed, or an error)."""

    def inputs(self) -> list[Path]:
        """The files :meth:`load` reads. The pipeline fingerprints their contents into every stage's
        artifact key (:func:`mocap.fingerprint.files_fingerprint`), so a clip edited in place is
        trained on again instead of being served from a stale stage. Default: none (the spec's
        params alone identify the data, e.g. clips generated from the params)."""
        return []


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
    "Imitator",
    "LatentSample",
    "LatentSpace",
    "Metric",
    "MotionSource",
    "MultiDiscrete",
    "Simulator",
    "StageResult",
    "Task",
    "Trainer",
)
