"""The pipeline runner: ``imitator -> latent -> task -> eval``, with artifacts reused across specs.

Each stage's artifact lives in ``<store>/<stage>-<key>/`` where ``key`` hashes the stage's
resolved section, the sections it depends on (humanoid, motions, simulator, seed) and the keys of
the stages upstream of it. A second spec with the same imitator section therefore finds the
trained imitator and reuses it; changing anything the imitator depends on gives a new key.

A stage is complete when its ``DONE.json`` exists (written atomically last). An incomplete
artifact directory holds the trainer's last checkpoint, so running the same command again
resumes it. A stage may instead name an existing ``checkpoint:`` (keyed by the file's content),
or name neither trainer nor checkpoint (an untrained component, e.g. a baseline).

Run directory (``runs/<spec name>`` unless ``--out``): ``spec.yaml`` (resolved), ``metrics.jsonl``,
``tb/`` (TensorBoard), ``stages.json`` (artifact dir and result of every stage), ``report.md``.

Under torchrun (:mod:`mocap.distributed`) every rank runs this same loop: rank 0 takes the artifact
lock, decides reuse and broadcasts its decision and each stage's result, and alone writes the run's
files; a trainer with ``data_parallel = True`` runs on every rank (seed :func:`mocap.distributed.rank_seed`
of the stage seed), any other trainer runs on rank 0 alone while the other ranks wait.
"""

from __future__ import annotations

import contextlib
import hashlib
import json
import shutil
import signal
import time
from dataclasses import dataclass, field, replace
from functools import cached_property
from pathlib import Path
from typing import Any, Callable, Iterator

import torch
from pydantic import BaseModel
from rich.console import Console

from mocap import distributed as dist
from mocap.errors import StageFailed, StorageError  # noqa: F401  (StageFailed: defined there, re-exported)
from mocap.checkpoint import atomic_write_json, atomic_write_text, hardware, package_versions
from mocap.interfaces import RLTrainable, StageResult, Trainer
from mocap.plugins import PluginError, PluginSet
from mocap.run_record import PUBLISHED_DIR, RunRecord, copy_published
from mocap.runlog import MetricsLogger
from mocap.skeleton import Skeleton
from mocap.spec import STAGES, ResolvedSpec, Spec, StageSpec
from mocap.stage_keys import (  # noqa: F401  (re-exported)
    ARTIFACT_FORMAT,
    KEY_FILE,
    earlier_keys,
    key_change,
    material_key,
    motion_fingerprint,
    resolved_stage_keys,
    resolved_stage_materials,
    stage_keys,
    why_new_key,
)

DONE_FILE = "DONE.json"


class PipelineInterrupted(Exception):
    """The user pressed Ctrl-C; the running stage saved a checkpoint and the run can be resumed."""


def derive_seed(seed: int, stage: str) -> int:
    """A per-stage seed, stable across runs and independent between stages."""
    return int.from_bytes(hashlib.sha256(f"{seed}:{stage}".encode()).digest()[:4], "little")


def resolve_device(name: str) -> torch.device:
    if name == "cuda" or (name == "auto" and torch.cuda.is_available()):
        if not torch.cuda.is_available():
            raise StageFailed("spec asks for device 'cuda' but torch sees no CUDA device")
        return torch.device("cuda")
    return torch.device("cpu")


@dataclass
class StageContext:
    """What a trainer gets to run one stage.

    Attributes:
        stage: ``imitator``, ``latent``, ``task`` or ``eval``.
        resolved: the validated spec (``resolved.spec``) and the params instances.
        plugins: the registry, to build components.
        workdir: this stage's artifact directory (checkpoints go here; resume from here).
        run_dir: the run directory (reports, videos).
        upstream: results of the stages before this one.
        log: metrics logger for this stage (``metrics.jsonl`` + TensorBoard in the run dir).
        seed: this stage's seed.
        device: torch device for networks.
        console: where to print progress.
    """

    stage: str
    resolved: ResolvedSpec
    plugins: PluginSet
    workdir: Path
    run_dir: Path
    upstream: dict[str, StageResult]
    log: MetricsLogger
    seed: int
    device: torch.device
    console: Console
    _stop: Callable[[], bool] = field(default=lambda: False, repr=False)
    #: the RL env factory of a sub-phase (:meth:`phase`); None: :meth:`make_rl_env` builds the stage's
    env_factory: Callable[[int], Any] | None = field(default=None, repr=False)
    #: in a :meth:`phase`: the stage's own artifact directory (where :meth:`publish` writes); None: ``workdir``
    stage_dir: Path | None = field(default=None, repr=False)

    @property
    def spec(self) -> Spec:
        return self.resolved.spec

    def should_stop(self) -> bool:
        """True once the user asked to stop (Ctrl-C): save a checkpoint and return."""
        return self._stop()

    def params(self, path: str) -> BaseModel | None:
        return self.resolved.params.get(path)

    def build(self, path: str, **kwargs: Any) -> Any:
        """Build the component at dotted spec ``path`` (``simulator``, ``latent``, ``task.trainer``...)."""
        from mocap.spec import iter_components

        for p, kind, ref in iter_components(self.spec):
            if p == path:
                return self.plugins.get(kind, ref.name).build(self.resolved.params.get(p), **kwargs)
        raise KeyError(f"the spec has no component at {path!r}")

    @cached_property
    def skeleton(self) -> Skeleton:
        return self.build("humanoid")

    def stage_component(self, stage: str | None = None, checkpoint: Path | None = None) -> Any:
        """Build a stage's component (imitator, latent space or task; default: this stage's).

        Stage components share one factory signature: ``factory(params, *, skeleton, checkpoint,
        device)``; ``checkpoint`` is None when the component is about to be trained. A checkpoint
        trained on another humanoid, or on this one with other parameters, is refused
        (:func:`mocap.eval_targets.check_trained_humanoid`).
        """
        stage = stage or self.stage
        if checkpoint is not None:  # a trained component acts through the humanoid it was trained on
            from mocap.eval_targets import check_trained_humanoid

            check_trained_humanoid(Path(checkpoint), self.skeleton, self.plugins, stage)
        component = self.build(stage, skeleton=self.skeleton, checkpoint=checkpoint, device=self.device)
        if stage == "latent" and checkpoint is not None:
            from mocap.distill_files import check_latent_loaded

            assert self.spec.latent is not None  # the latent component was just built from it
            check_latent_loaded(component, Path(checkpoint), self.spec.latent.name)
        return component

    def phase(
        self,
        name: str,
        *,
        workdir: Path,
        seed: int | None = None,
        env_factory: Callable[[int], Any] | None = None,
        stop: Callable[[], bool] | None = None,
    ) -> "StageContext":
        """A child context for a sub-phase that another trainer runs inside this stage (PMCP's
        primitives, VMP's VAE and tracker under PPO or the supervised trainer): its own ``workdir``
        (its checkpoints and resume), its own rows in ``metrics.jsonl`` (``log`` labelled
        ``<stage>/<name>``: close it when the phase ends), optionally its own ``seed``, RL env
        (``env_factory(num_envs)``, used by :meth:`make_rl_env`) and an extra ``stop`` condition
        (the parent's Ctrl-C still stops it). Published files (:meth:`publish`) reach the run
        directory as the parent's do. Everything else is the parent's."""
        parent_stop = self._stop
        halt = parent_stop if stop is None else (lambda: bool(stop()) or bool(parent_stop()))
        return replace(
            self,
            workdir=Path(workdir),
            log=self.log.child(name),
            seed=self.seed if seed is None else int(seed),
            env_factory=env_factory if env_factory is not None else self.env_factory,
            stage_dir=self.stage_dir if self.stage_dir is not None else self.workdir,
            _stop=halt,
        )

    def make_rl_env(self, num_envs: int) -> Any:
        """The RL problem of this stage: ``stage_component().make_env(self, num_envs)`` (a VecEnv);
        for the ``task`` stage, :func:`mocap.task_env.make_task_env` (the task through the latent space);
        in a :meth:`phase` with an ``env_factory``, that factory's env."""
        if self.env_factory is not None:
            return self.env_factory(num_envs)
        if self.stage == "task" and self.spec.latent is not None:
            from mocap.task_env import make_task_env

            return make_task_env(self, num_envs)
        if self.stage == "task" and self.spec.task is not None:
            import inspect

            # a task factory (params, *, skeleton, num_envs, device) runs through a latent space; a task
            # component built like a stage component (checkpoint, device) may be RLTrainable itself
            factory = self.plugins.get("task", self.spec.task.name).resolved_factory()
            if "num_envs" in inspect.signature(factory).parameters:
                raise StageFailed("the task stage needs a latent space (use `latent: {name: scratch}` for a policy without one)")
        component = self.stage_component()
        if not isinstance(component, RLTrainable):
            raise StageFailed(f"{self.stage} {getattr(self.spec, self.stage).name!r} cannot be trained by RL (it is not RLTrainable: no make_env)")
        return component.make_env(self, num_envs)

    def spec_yaml(self) -> str:
        return self.resolved.to_yaml()

    def publish(self, name: str) -> Path:
        """Path under which to write an output file ``name`` for the run directory (a table, a
        video). The pipeline copies it there; a later run that reuses this stage gets it too."""
        from mocap.paths import confined

        root = self.stage_dir if self.stage_dir is not None else self.workdir  # a phase publishes for its stage
        path = confined(root / PUBLISHED_DIR, name)  # a name built from data never leaves the folder
        path.parent.mkdir(parents=True, exist_ok=True)
        return path


@dataclass
class StageRecord:
    stage: str
    key: str
    workdir: Path
    result: StageResult
    reused: bool
    seconds: float
    trained_seconds: float | None = None  # a reused artifact: how long its training took when it was made
    why: str | None = None  # trained although this run directory had run the stage before: what changed


class _StopFlag:
    """First Ctrl-C asks the running stage to stop cleanly; a second one interrupts at once."""

    def __init__(self, console: Console):
        self.console = console
        self.requested = False
        self._previous: Any = None

    def __enter__(self) -> "_StopFlag":
        try:
            self._previous = signal.signal(signal.SIGINT, self._handle)
        except ValueError:  # not in the main thread (e.g. some test runners): no handler
            self._previous = None
        return self

    def _handle(self, signum: int, frame: Any) -> None:
        if self.requested:
            raise KeyboardInterrupt
        self.requested = True
        self.console.print("[yellow]stopping after the current iteration (checkpoint will be saved); Ctrl-C again to abort[/]")

    def __exit__(self, *exc: Any) -> None:
        if self._previous is not None:
            signal.signal(signal.SIGINT, self._previous)


def artifact_store(out_dir: Path) -> Path:
    """Artifacts are shared by every run under the same parent directory (``runs/artifacts``)."""
    return out_dir.parent / "artifacts"


def run_pipeline(
    resolved: ResolvedSpec,
    plugins: PluginSet,
    out_dir: Path,
    *,
    store: Path | None = None,
    console: Console | None = None,
) -> list[StageRecord]:
    """Run every stage the spec names, reusing finished artifacts; return what each stage did."""
    console = console or Console()
    out_dir = Path(out_dir)
    store = Path(store) if store is not None else artifact_store(out_dir)
    main = dist.is_main()  # rank 0 under torchrun, else the one process
    if not main:  # the other ranks of a data-parallel run are quiet and write nothing
        console = _quiet_console()
    run_lock: contextlib.AbstractContextManager[None] = contextlib.nullcontext()
    if main:
        try:
            out_dir.mkdir(parents=True, exist_ok=True)
        except OSError as exc:  # a full disk, a read-only folder: one line naming it
            raise StorageError(out_dir, exc) from exc
        run_lock = run_dir_lock(out_dir)
    with run_lock:
        return _run_pipeline_locked(resolved, plugins, out_dir, store, console, main)


RUN_LOCK = ".mocap-run.lock"


@contextlib.contextmanager
def run_dir_lock(out_dir: Path) -> Iterator[None]:
    """Exclusive use of a run directory for the whole run: a second ``mocap run`` into the same
    directory is refused at once (StageFailed naming the holder's pid) instead of interleaving its
    metrics and overwriting the spec. An OS lock (``flock``): a killed run releases it."""
    import fcntl

    path = Path(out_dir) / RUN_LOCK
    try:
        fh = path.open("a+")
    except OSError as exc:  # a disk full before the run starts, a read-only folder
        raise StorageError(path, exc) from exc
    with fh:
        try:
            fcntl.flock(fh, fcntl.LOCK_EX | fcntl.LOCK_NB)
        except BlockingIOError:
            fh.seek(0)
            holder = fh.read().strip() or "unknown"
            raise StageFailed(
                f"{out_dir}: another mocap run (pid {holder}) is writing to this run directory; wait for it to finish, or choose another --out"
            ) from None
        try:
            try:
                _write_pid(fh.fileno())
            except OSError as exc:
                raise StorageError(path, exc) from exc
            yield
        finally:
            fcntl.flock(fh, fcntl.LOCK_UN)


def _write_pid(fd: int) -> None:
    """Make the open lock file ``fd`` hold this process's pid (unbuffered: a full disk fails here,
    not later when the file is closed). One function, so that tests can simulate a full disk."""
    import os

    os.ftruncate(fd, 0)
    os.write(fd, str(os.getpid()).encode())


def _preflight(resolved: ResolvedSpec, plugins: PluginSet, keys: dict[str, str], store: Path) -> None:
    """Every stage that will train: its trainer's :meth:`~mocap.interfaces.Trainer.preflight` checks,
    before the first stage starts (a finished, reused stage is not checked again)."""
    for stage, key in keys.items():
        section = getattr(resolved.spec, stage)
        if section is None or section.trainer is None or (isinstance(section, StageSpec) and section.checkpoint):
            continue
        if (store / f"{stage}-{key}" / DONE_FILE).is_file():
            continue
        trainer = _as_trainer(plugins.get("trainer", section.trainer.name).build(resolved.params.get(f"{stage}.trainer")), section.trainer.name)
        trainer.preflight(resolved, plugins)


def _as_trainer(trainer: Any, name: str) -> Trainer:
    """``trainer`` if it is a :class:`~mocap.interfaces.Trainer`, else a one-line plugin error."""
    if not isinstance(trainer, Trainer):
        raise PluginError(f"trainer {name!r} built a {type(trainer).__name__}, not a mocap.interfaces.Trainer")
    return trainer


def _run_pipeline_locked(resolved: ResolvedSpec, plugins: PluginSet, out_dir: Path, store: Path, console: Console, main: bool) -> list[StageRecord]:
    spec = resolved.spec
    files = RunRecord(out_dir, resolved, main)
    if spec.torch_threads is not None:
        torch.set_num_threads(spec.torch_threads)
    device = dist.init(resolve_device(spec.device))  # under torchrun: join the group; this rank's device
    if dist.world_size() > 1:
        console.print(f"data-parallel: {dist.world_size()} processes ({device.type}); rank 0 writes {out_dir}", highlight=False)
    materials = resolved_stage_materials(resolved, plugins)
    keys = {stage: material_key(m) for stage, m in materials.items()}
    earlier = earlier_keys(out_dir) if main else {}
    _preflight(resolved, plugins, keys, store)
    upstream: dict[str, StageResult] = {}
    started = time.time()
    with _StopFlag(console) as stop:
        for stage in STAGES:
            if stage not in keys:
                continue
            why = why_new_key(store, stage, earlier.get(stage), materials[stage]) if earlier.get(stage) not in (None, keys[stage]) else None
            record = _run_stage(stage, keys[stage], resolved, plugins, out_dir, store, upstream, device, console, stop, (materials[stage], why, files.start))
            files.add(record)
            upstream[stage] = record.result
            if stop.requested:
                raise PipelineInterrupted(stage)
    files.start()
    records = files.records
    if main:
        from mocap.report import write_report

        write_report(out_dir, resolved, records, wall_seconds=time.time() - started)
    dist.barrier()  # the run's files are complete before any rank returns
    return records


def _quiet_console() -> Console:
    import io

    return Console(file=io.StringIO(), quiet=True)


def _run_stage(
    stage: str,
    key: str,
    resolved: ResolvedSpec,
    plugins: PluginSet,
    out_dir: Path,
    store: Path,
    upstream: dict[str, StageResult],
    device: torch.device,
    console: Console,
    stop: _StopFlag,
    key_info: tuple[dict[str, Any], str | None, Callable[[], None]] = ({}, None, lambda: None),
) -> StageRecord:
    if dist.is_main():
        store.mkdir(parents=True, exist_ok=True)
    # data-parallel: rank 0 holds the lock for all ranks (the others follow its decisions)
    lock = _stage_lock(store / f".{stage}-{key}.lock", stage, console) if dist.is_main() else contextlib.nullcontext()
    with lock:
        return _run_stage_locked(stage, key, resolved, plugins, out_dir, store, upstream, device, console, stop, key_info)


@contextlib.contextmanager
def _stage_lock(path: Path, stage: str, console: Console) -> Iterator[None]:
    """An exclusive lock per artifact: two runs (e.g. cells of a comparison run in parallel) that
    need the same stage train it once; the second waits and then reuses the artifact."""
    import fcntl

    with path.open("a") as fh:
        try:
            fcntl.flock(fh, fcntl.LOCK_EX | fcntl.LOCK_NB)
        except BlockingIOError:
            console.print(f"[yellow]{stage}[/]: another run is training this stage; waiting for it")
            fcntl.flock(fh, fcntl.LOCK_EX)
        try:
            yield
        finally:
            fcntl.flock(fh, fcntl.LOCK_UN)


def _run_stage_locked(
    stage: str,
    key: str,
    resolved: ResolvedSpec,
    plugins: PluginSet,
    out_dir: Path,
    store: Path,
    upstream: dict[str, StageResult],
    device: torch.device,
    console: Console,
    stop: _StopFlag,
    key_info: tuple[dict[str, Any], str | None, Callable[[], None]] = ({}, None, lambda: None),
) -> StageRecord:
    material, why, start_run = key_info  # start_run: this run writes its record from now on
    spec = resolved.spec
    section = getattr(spec, stage)
    workdir = store / f"{stage}-{key}"
    done = workdir / DONE_FILE
    t0 = time.time()
    main = dist.is_main()
    # rank 0 decides (under the artifact lock) and the other ranks take its answer
    reuse = dist.broadcast_object(_read_result(done) if main and done.is_file() else None)
    if reuse is not None:
        console.print(f"[green]{stage}[/]: reusing the trained artifact {workdir} (same {stage} section and upstream as an earlier run)")
        return StageRecord(stage, key, workdir, reuse, True, 0.0, _read_seconds(done) if main else None)
    checkpoint = getattr(section, "checkpoint", None)
    if checkpoint is not None:
        if not dist.broadcast_object(Path(checkpoint).is_file()):
            raise StageFailed(
                f"{stage}.checkpoint: {checkpoint}: no such file (looked for {Path(checkpoint).resolve()}; paths written in a "
                "spec file are relative to that file, paths given with --set relative to the working directory)"
            )
        console.print(f"[green]{stage}[/]: using checkpoint {checkpoint}")
        return StageRecord(stage, key, workdir, StageResult(checkpoint=Path(checkpoint)), True, 0.0)
    trainer_ref = section.trainer
    if trainer_ref is None:
        console.print(f"[green]{stage}[/]: {section.name} needs no training")
        return StageRecord(stage, key, workdir, StageResult(checkpoint=None), False, 0.0)
    start_run()  # a stage really starts: from here on the run directory is this run's
    if main:
        workdir.mkdir(parents=True, exist_ok=True)
        atomic_write_text(workdir / "spec.yaml", resolved.to_yaml())
        atomic_write_json(workdir / KEY_FILE, material)
        if why:
            console.print(f"[yellow]{stage}[/]: training again, its artifact key changed since this run directory's last run: {why}", highlight=False)
    dist.barrier()  # the stage directory exists for every rank
    log = MetricsLogger(out_dir / "metrics.jsonl", stage, tensorboard_dir=out_dir / "tb")  # writes on rank 0 only
    ctx = StageContext(
        stage=stage,
        resolved=resolved,
        plugins=plugins,
        workdir=workdir,
        run_dir=out_dir,
        upstream=dict(upstream),
        log=log,
        seed=derive_seed(spec.seed, stage),
        device=device,
        console=console,
        _stop=lambda: stop.requested,
    )
    trainer = _as_trainer(ctx.build(f"{stage}.trainer"), trainer_ref.name)
    resuming = any(workdir.glob("*.pt"))
    if main and not resuming:  # rows of an earlier attempt killed before its first checkpoint (e.g. an eval stage)
        log.truncate_after(-1)
    verb = "resuming" if resuming else "running"
    console.print(f"[bold]{stage}[/]: {verb} trainer {trainer_ref.name!r} in {workdir}")
    parallel = dist.world_size() > 1
    data_parallel = parallel and trainer.data_parallel
    if data_parallel:
        ctx.seed = dist.rank_seed(ctx.seed)  # each rank its own environments
    elif parallel:
        console.print(
            f"[yellow]{stage}[/]: trainer {trainer_ref.name!r} is not data-parallel; rank 0 runs it alone "
            f"while the other {dist.world_size() - 1} process(es) wait",
            highlight=False,
        )
    result: StageResult | None = None
    try:
        if data_parallel or not parallel:
            result = trainer.run(ctx)
        elif main:
            with dist.solo():
                result = trainer.run(ctx)
    except BaseException:
        if main:
            _remove_if_empty(workdir)
        raise
    finally:
        log.close()
        if main:
            copy_published(workdir, out_dir)
    if parallel:
        # all ranks agree on an interruption (Ctrl-C reaching any of them) and on rank 0's result
        if dist.any_true(stop.requested):
            stop.requested = True
        result = dist.broadcast_object(result)
    assert result is not None
    if not stop.requested and main:
        atomic_write_json(
            done,
            {
                "stage": stage,
                "key": key,
                "checkpoint": str(result.checkpoint) if result.checkpoint else None,
                "metrics": result.metrics,
                "versions": package_versions(),
                "hardware": hardware(),
                "seconds": round(time.time() - t0, 2),
            },
        )
    return StageRecord(stage, key, workdir, result, False, time.time() - t0, why=why)


def _read_result(done: Path) -> StageResult:
    data = json.loads(done.read_text(encoding="utf-8"))
    ckpt = data.get("checkpoint")
    return StageResult(checkpoint=Path(ckpt) if ckpt else None, metrics=data.get("metrics", {}))


def _remove_if_empty(workdir: Path) -> None:
    """Remove a stage folder that a failed first attempt left with nothing but its ``spec.yaml`` and
    ``key.json`` (no checkpoint, no output): it would only litter the artifact store."""
    try:
        items = [p for p in workdir.iterdir() if p.name not in ("spec.yaml", KEY_FILE)]
    except OSError:
        return
    if not items:
        shutil.rmtree(workdir, ignore_errors=True)


def _read_seconds(done: Path) -> float | None:
    """The training time recorded in an artifact's DONE.json (None if absent or unreadable)."""
    try:
        value = json.loads(done.read_text(encoding="utf-8")).get("seconds")
    except (OSError, ValueError, AttributeError):
        return None
    return float(value) if isinstance(value, (int, float)) else None
