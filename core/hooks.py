"""Hook specifications: every hook is a registration callback (the ``llm``/``datasette`` style).

A plugin is a module (or object) with functions decorated by :data:`hookimpl`, named after the
hooks below, and published under the entry-point group ``mocap``::

    # my_plugin.py
    from mocap.hooks import hookimpl

    @hookimpl
    def register_tasks(register):
        register("balance", BalanceTask, params=BalanceParams, description="stand still")

``register(name, factory, params=None, description="")`` records one component: ``factory`` is
called with the validated ``params`` model instance (or with no argument when ``params`` is None)
plus the keyword arguments the role documents (see :mod:`mocap.interfaces`). ``params`` is a
pydantic model that validates the component's ``params:`` section of a spec.

``metrics={"speed_error": MetricInfo("speed error", "m/s")}`` (keyword; ``(display, unit)`` tuples
are accepted) declares how the metrics the component reports are shown in ``report.md``,
comparison tables and the end-of-run summary (:mod:`mocap.metric_display`); an undeclared metric is
shown by its key.
"""

from __future__ import annotations

from typing import Any, Callable, Mapping, Protocol

import pluggy

PROJECT = "mocap"
ENTRY_POINT_GROUP = "mocap"

hookspec = pluggy.HookspecMarker(PROJECT)
hookimpl = pluggy.HookimplMarker(PROJECT)


class Register(Protocol):
    def __call__(
        self,
        name: str,
        factory: Callable[..., Any],
        params: type | None = None,
        description: str = "",
        *,
        metrics: Mapping[str, Any] | None = None,
    ) -> None: ...


@hookspec
def register_simulators(register: Register) -> None:
    """Register simulators: ``factory(params, *, skeleton, num_envs, seed, **_) -> Simulator``.

    The framework passes no device: a simulator keeps its state where its engine runs (the MuJoCo
    simulator on the CPU; ``mujoco_warp`` on its GPU) and says so with ``Simulator.device``."""


@hookspec
def register_humanoids(register: Register) -> None:
    """Register humanoids: ``factory(params) -> Skeleton``."""


@hookspec
def register_motion_sources(register: Register) -> None:
    """Register motion sources: ``factory(params) -> MotionSource`` (``.load(skeleton) -> MotionSet``)."""


@hookspec
def register_imitators(register: Register) -> None:
    """Register imitators: ``factory(params, *, skeleton, checkpoint, device) -> Imitator``.

    ``checkpoint`` is the imitator stage's trained checkpoint (None for untrained baselines);
    ``device`` is always a :class:`torch.device` (the stage's, ``mocap run --device``).
    """


@hookspec
def register_latent_spaces(register: Register) -> None:
    """Register latent spaces: ``factory(params, *, skeleton, checkpoint, device) -> LatentSpace``.

    ``checkpoint`` is the latent stage's ``latent.pt`` (None when it is about to be trained): the
    factory must load it; ``device`` is always a :class:`torch.device`."""


@hookspec
def register_tasks(register: Register) -> None:
    """Register downstream tasks: ``factory(params, *, skeleton, num_envs, device) -> Task``.

    ``device`` is always a :class:`torch.device`; the task env runs tasks on the CPU
    (``torch.device("cpu")``), next to the simulator's state.

    A task that follows a reference motion (tracking, in-betweening) also declares a keyword
    ``motions``: the task stage then passes the env's :class:`~mocap.motion.library.MotionLibrary`.
    Accept and ignore other keywords (``**_``) so that later framework versions can add some.
    """


@hookspec
def register_trainers(register: Register) -> None:
    """Register trainers: ``factory(params) -> Trainer`` (runs one pipeline stage)."""


@hookspec
def register_metrics(register: Register) -> None:
    """Register metrics: ``factory(params) -> Metric``."""


@hookspec
def register_commands(app: Any) -> None:
    """Add commands to the ``mocap`` CLI: ``app`` is the root :class:`typer.Typer`."""


#: hook name -> registry kind (the role name used in specs, errors and ``mocap plugins``).
REGISTRATION_HOOKS: dict[str, str] = {
    "register_simulators": "simulator",
    "register_humanoids": "humanoid",
    "register_motion_sources": "motion_source",
    "register_imitators": "imitator",
    "register_latent_spaces": "latent",
    "register_tasks": "task",
    "register_trainers": "trainer",
    "register_metrics": "metric",
}
