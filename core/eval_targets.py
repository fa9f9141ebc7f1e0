"""What ``mocap eval``, ``generate``, ``render`` and ``play`` evaluate: a checkpoint, a checkpoint
directory, a run directory or a spec, resolved to a validated spec and its stage checkpoints
(:func:`load_evaluation_target`), then built into a skeleton, motion library, policy and simulator
factory (:func:`build_evaluation_target`). Re-exported by :mod:`mocap.evaluation`."""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path
from typing import Any, Callable

import torch

from mocap.distill_files import check_latent_loaded
from mocap.interfaces import Imitator, Simulator
from mocap.motion.library import MotionLibrary


@dataclass
class EvalTarget:
    """What ``mocap eval`` / ``mocap generate`` evaluate: a validated spec and the stage checkpoints.

    ``latent_checkpoint`` is set when the target is a latent space; it is then evaluated as an
    imitator (:class:`~mocap.latent_imitator.LatentImitator`, ``z`` = encoder mean) on top of the
    imitator it was distilled from (``imitator_checkpoint``). ``code_note``: for a checkpoint file,
    what differs between the plugin code it records and the installed code (:func:`code_difference`;
    ``mocap eval`` prints it as one ``note:`` line after its results), None when they match.
    """

    resolved: Any
    imitator_checkpoint: Path | None
    latent_checkpoint: Path | None = None
    code_note: str | None = None

    @property
    def spec(self) -> Any:
        return self.resolved.spec


@dataclass
class LoadedTarget:
    """An :class:`EvalTarget` built: skeleton, motion library, the policy to evaluate, and the parts."""

    target: EvalTarget
    skeleton: Any
    library: MotionLibrary
    imitator: Imitator  # the trained imitator (the teacher, for a latent)
    latent: Any  # the latent space, or None
    label: str  # what the latent's decoder outputs: "policy_output" (teacher's raw output) or "pd_targets"
    policy: Imitator  # what imitation evaluation rolls out
    make_sim: Callable[[int], Simulator]
    own_tracker: bool = False  # ``policy`` is the latent's own tracking policy (VMP); ``imitator`` is then the spec's, when it names one

    def to_pd_targets(self, obs: Any, output: torch.Tensor) -> torch.Tensor:
        """PD targets from a latent decoder's output (identity for ``label: pd_targets``)."""
        return output if self.label == "pd_targets" else self.imitator.to_pd_targets(obs, output)


_POLICY_NAMES = ("latent.pt", "policy.pt")


def _stage_checkpoint(spec: Any, stage: str) -> Path | None:
    section = getattr(spec, stage)  # a Spec field (imitator, latent, task): None when the spec has no such stage
    ckpt = getattr(section, "checkpoint", None) if section is not None else None
    return Path(ckpt) if ckpt else None


def _from_file(target: Path, plugins: Any) -> EvalTarget:
    from mocap.checkpoint import load_checkpoint
    from mocap.errors import UserError
    from mocap.spec import SpecError, load_spec, validate_document

    if target.suffix in (".yaml", ".yml"):
        try:
            resolved = load_spec(target, plugins)
        except SpecError as exc:
            raise UserError(str(exc)) from None
        return _check(EvalTarget(resolved, _stage_checkpoint(resolved.spec, "imitator"), _stage_checkpoint(resolved.spec, "latent")), target)
    data = load_checkpoint(target)  # CheckpointError (missing, corrupt, truncated): one clear line
    _check_known_format(target, data)
    _warn_unfinished(target, data)
    spec_yaml = data.get("spec") if isinstance(data, dict) else None
    if not spec_yaml:
        raise UserError(f"{target}: the checkpoint carries no spec; evaluate its run directory instead")
    from mocap.export import resolve_embedded_paths

    from mocap.runfiles import yaml_mapping

    doc = resolve_embedded_paths(yaml_mapping(spec_yaml, f"{target} (embedded spec)"), target.parent)
    resolved = validate_document(doc, plugins, source=f"{target} (embedded spec)", provenance=data.get("components"))
    note = code_difference(data.get("components"), resolved, plugins)
    from mocap.distill_files import CHECKPOINT_FORMAT as DISTILL_FORMAT, LATENT_FORMAT

    if data.get("format") in (LATENT_FORMAT, DISTILL_FORMAT) or (resolved.spec.imitator is None and resolved.spec.latent is not None):
        teacher = _stage_checkpoint(resolved.spec, "imitator")
        return _check(EvalTarget(resolved, teacher, target, note), target)
    return _check(EvalTarget(resolved, target, code_note=note), target)


def code_difference(recorded: Any, resolved: Any, plugins: Any) -> str | None:
    """What differs between the plugin code a checkpoint recorded (its ``components``:
    :meth:`mocap.plugins.PluginSet.provenance`) and the installed code, for the components its
    spec names; None when they match. A checkpoint from before code fingerprints says so."""
    from mocap.plugins import PluginError
    from mocap.spec import iter_components

    if not isinstance(recorded, dict) or not any(isinstance(v, dict) and "code" in v for v in recorded.values()):
        return "it records no plugin code fingerprint (written before mocap recorded one), so it cannot tell whether the installed code made it"
    changed = []
    for _, kind, ref in iter_components(resolved.spec):
        entry = recorded.get(f"{kind}:{ref.name}")
        if not isinstance(entry, dict) or "code" not in entry:
            continue
        try:
            now = plugins.code_of(kind, ref.name)
        except PluginError:
            continue
        then = f"{str(entry.get('package'))[:60]} {str(entry.get('version'))[:30]} code {str(entry.get('code'))[:16]}"
        if (now["package"], now["version"], now["code"]) != (entry.get("package"), entry.get("version"), entry.get("code")):
            changed.append(f"{kind}:{ref.name} ({then}; installed: {now['package']} {now['version']} code {now['code']})")
    if not changed:
        return None
    more = f" and {len(changed) - 3} more" if len(changed) > 3 else ""
    return "it was made by other plugin code than the installed one: " + "; ".join(changed[:3]) + more


def _warn_unfinished(path: Path, data: dict[str, Any]) -> None:
    """One ``warning:`` line when a trainer checkpoint was saved before the end of its budget (eval,
    generate, render and export all load targets through here)."""
    from rich.console import Console

    from mocap.checkpoint import training_status

    status = training_status(data)
    if status is not None:
        Console(stderr=True, soft_wrap=True).print(
            f"[yellow]warning:[/] {path} is a training checkpoint still {status}; the numbers describe an unfinished policy",
            highlight=False,
        )


def _check_known_format(path: Path, data: dict[str, Any]) -> None:
    """A policy / latent / trainer checkpoint of a format version this mocap does not read: a
    :class:`~mocap.checkpoint.CheckpointError` naming both versions (other formats pass: their
    plugin checks them)."""
    from mocap.checkpoint import check_format, split_format
    from mocap.distill_files import CHECKPOINT_FORMAT as DISTILL_FORMAT, LATENT_FORMAT
    from mocap.rl.networks import POLICY_FORMAT
    from mocap.rl.ppo import CHECKPOINT_FORMAT as PPO_FORMAT

    known = (POLICY_FORMAT, PPO_FORMAT, LATENT_FORMAT, DISTILL_FORMAT)
    got = split_format(data.get("format"))
    if got is not None and data.get("format") not in known and any(split_format(k)[0] == got[0] for k in known):  # type: ignore[index]
        check_format(path, data, known)


def _check(t: EvalTarget, source: Path) -> EvalTarget:
    from mocap.errors import UserError

    spec = t.spec
    if spec.imitator is None and t.latent_checkpoint is None:
        raise UserError(f"{source}: its spec has no imitator")
    if t.latent_checkpoint is not None and spec.latent is None:
        raise UserError(f"{source}: a latent checkpoint, but its spec has no latent stage")
    if t.latent_checkpoint is not None and t.imitator_checkpoint is None and spec.imitator is not None and spec.imitator.name not in ("pd_replay",):
        raise UserError(f"{source}: the latent's imitator has no checkpoint (the spec names none, and no run records one)")
    for path in (t.imitator_checkpoint, t.latent_checkpoint):
        if path is not None and not Path(path).is_file():
            raise UserError(f"{source}: checkpoint {path} does not exist (moved? evaluate a directory holding it)")
    return t


def _action_count(data: dict[str, Any]) -> int | None:
    """The number of actions of the policy in a checkpoint (policy file or PPO checkpoint), if it has one."""
    from mocap.rl.networks import POLICY_FORMAT

    config = data.get("config") if data.get("format") == POLICY_FORMAT else data.get("policy_config")
    space = config.get("action_space") if isinstance(config, dict) else None
    if isinstance(space, dict) and space.get("type") == "box" and space.get("shape"):
        return int(space["shape"][0])
    return None


def check_trained_humanoid(path: Path, skeleton: Any, plugins: Any, stage: str = "imitator") -> None:
    """Raise :class:`~mocap.checkpoint.CheckpointError` when the spec embedded in checkpoint ``path``
    names another humanoid than ``skeleton``: "trained for humanoid amp with 28 actions; the spec
    asks for smpl with 69", or the same humanoid with other parameters
    (:func:`mocap.humanoid_match.check_humanoid_params`)."""
    from mocap.checkpoint import CheckpointError, embedded_humanoid, load_checkpoint

    data = load_checkpoint(path)
    trained = embedded_humanoid(data)
    if trained is None:
        return
    if trained == skeleton.name:
        from mocap.humanoid_match import check_humanoid_params

        check_humanoid_params(path, data, skeleton, plugins, stage)
        return
    actions = _action_count(data)
    if actions is None:
        try:
            actions = plugins.get("humanoid", trained).build(None).num_dofs
        except Exception:  # noqa: BLE001 - a humanoid this install lacks: say so without the count
            actions = None
    count = f" with {actions} actions" if actions is not None else ""
    raise CheckpointError(
        f"{path}: this {stage} checkpoint was trained for humanoid {trained}{count}; the spec asks for "
        f"{skeleton.name} with {skeleton.num_dofs}. Use a checkpoint trained on {skeleton.name}, or set humanoid: {trained}"
    )


def load_evaluation_target(target: Path, plugins: Any) -> EvalTarget:
    """The :class:`EvalTarget` of a checkpoint file, a run directory, a checkpoint directory or a spec.

    * a file ``policy.pt`` / ``ppo.pt`` (imitator) or ``latent.pt`` / ``distill.pt`` (latent space):
      its embedded spec; for a latent, the imitator checkpoint that spec names;
    * a run directory (``spec.yaml`` + ``stages.json``): the imitator and latent stages' checkpoints
      (the latent is evaluated when the run has one);
    * a checkpoint directory (``checkpoints/<name>/``): its ``spec.yaml`` whose stages name their
      ``checkpoint:`` files (relative to it), else its ``latent.pt`` or ``policy.pt``;
    * a spec file whose imitator (and latent) stages name ``checkpoint:`` files.
    """
    from mocap.errors import UserError
    from mocap.spec import SpecError, load_spec, validate_document

    target = Path(target)
    if target.is_dir():
        spec_file, stages_file = target / "spec.yaml", target / "stages.json"
        if stages_file.is_file() and spec_file.is_file():
            from mocap.runfiles import read_spec_file, read_stages

            resolved = validate_document(read_spec_file(spec_file), plugins, source=str(spec_file))
            found: dict[str, Path] = {}
            for record in read_stages(stages_file):
                if record["stage"] in ("imitator", "latent") and record.get("checkpoint"):
                    found[record["stage"]] = Path(record["checkpoint"])
            if resolved.spec.imitator is None and "latent" not in found:
                raise UserError(f"{spec_file}: the run has no imitator or trained latent stage to evaluate")
            from mocap.pipeline import resolved_stage_keys

            keys = resolved_stage_keys(resolved, plugins)
            for stage in ("imitator", "latent"):
                section = getattr(resolved.spec, stage)
                if section is not None and section.trainer is not None and stage not in found:
                    partial = sorted((target.parent / "artifacts" / f"{stage}-{keys[stage]}").glob("*.pt"))
                    hint = f"; evaluate its latest training checkpoint instead: mocap eval {partial[0]}" if partial else "; run it first"
                    raise UserError(f"{target}: the {stage} stage has not finished (no checkpoint in stages.json){hint}")
            return _check(EvalTarget(resolved, found.get("imitator"), found.get("latent")), target)
        if spec_file.is_file():
            try:
                resolved = load_spec(spec_file, plugins)
            except SpecError as exc:
                raise UserError(str(exc)) from None
            t = EvalTarget(resolved, _stage_checkpoint(resolved.spec, "imitator"), _stage_checkpoint(resolved.spec, "latent"))
            return _check(t, target)
        for name in _POLICY_NAMES:
            if (target / name).is_file():
                return _from_file(target / name, plugins)
        raise UserError(f"{target}: not a run directory (spec.yaml + stages.json) nor a checkpoint directory ({' or '.join(_POLICY_NAMES)})")
    if not target.is_file():
        raise UserError(f"{target}: no such checkpoint file, spec or directory")
    return _from_file(target, plugins)


def _is_distilled(path: Path) -> bool:
    """Whether a latent checkpoint is a distilled latent space (``mocap.latent`` / ``mocap.distill``
    format, decoded through the imitator it was distilled from) rather than a latent space with a
    policy of its own (VMP's tracker)."""
    from mocap.checkpoint import load_checkpoint
    from mocap.distill_files import CHECKPOINT_FORMAT, LATENT_FORMAT

    return load_checkpoint(path).get("format") in (LATENT_FORMAT, CHECKPOINT_FORMAT)


def motion_source_by_name(plugins: Any, name: str, option: str = "--motions") -> Any:
    """The motion source ``name`` with its default params (``--motions NAME``), or a
    :class:`~mocap.errors.UserError` when it cannot be built without params (e.g. ``amass`` and
    ``npz``, which need the ``paths`` of the files): evaluating on one's own files takes a spec."""
    from pydantic import ValidationError

    from mocap.errors import UserError

    component = plugins.get("motion_source", name)
    if component.params is not None:
        try:
            component.params.model_validate({})
        except ValidationError as exc:
            fields = ", ".join(sorted({".".join(str(part) for part in err["loc"]) or "params" for err in exc.errors()}))
            raise UserError(
                f"{option} {name}: the motion source {name!r} needs params ({fields}), which {option} cannot give; to evaluate "
                f"on your own files, write a spec whose motions: section is {{name: {name}, params: {{{fields}: ...}}}} and whose "
                "imitator (and latent) name their checkpoint: files, then `mocap eval that.yaml`"
            ) from None
    return component.build(None)


def build_evaluation_target(target: EvalTarget, plugins: Any, *, motions: str | None = None, device: str = "cpu", use_latent: bool = True) -> LoadedTarget:
    """Build the skeleton, motion library (``motions``: another source, default params), the
    imitator, the latent space (when ``target`` has one and ``use_latent``) and the simulator factory."""
    from mocap.distill_files import load_latent_state
    from mocap.latent_imitator import PDTargetTeacher, latent_imitator

    resolved, spec = target.resolved, target.spec
    skeleton = plugins.get("humanoid", spec.humanoid.name).build(resolved.params.get("humanoid"))
    for stage, path in (("imitator", target.imitator_checkpoint), ("latent", target.latent_checkpoint)):
        if path is not None:  # before loading motions: a checkpoint for another humanoid fails at once
            check_trained_humanoid(Path(path), skeleton, plugins, stage)
    if motions is None:
        source = plugins.get("motion_source", spec.motions.name).build(resolved.params.get("motions"))
    else:
        source = motion_source_by_name(plugins, motions)
    lib = MotionLibrary(source.load(skeleton), skeleton)
    sim_component = plugins.get("simulator", spec.simulator.name)
    sim_params = resolved.params.get("simulator")

    def make_sim(n: int) -> Simulator:
        return sim_component.build(sim_params, skeleton=skeleton, num_envs=n, seed=spec.seed)

    own_tracker = spec.imitator is None or (use_latent and target.latent_checkpoint is not None and not _is_distilled(Path(target.latent_checkpoint)))
    if own_tracker:  # a latent space that imitates on its own (VMP's tracker), even where the spec names an imitator
        from mocap.errors import UserError

        latent = plugins.get("latent", spec.latent.name).build(
            resolved.params.get("latent"), skeleton=skeleton, checkpoint=target.latent_checkpoint, device=device
        )
        if target.latent_checkpoint is not None:
            check_latent_loaded(latent, Path(target.latent_checkpoint), spec.latent.name)
        probe = make_sim(1)
        dt = float(probe.dt)
        probe.close()
        own = latent.as_imitator(lib, dt=dt, device=device)
        if own is None:
            raise UserError(f"{target.latent_checkpoint}: the {spec.latent.name} latent has no imitator of its own and the spec names none")
        teacher: Imitator = own
        if spec.imitator is not None and target.imitator_checkpoint is not None:  # the imitator it was distilled from (VMP's warm start)
            teacher = plugins.get("imitator", spec.imitator.name).build(
                resolved.params.get("imitator"), skeleton=skeleton, checkpoint=target.imitator_checkpoint, device=device
            )
        return LoadedTarget(target, skeleton, lib, teacher, latent, "pd_targets", own, make_sim, own_tracker=True)
    imitator = plugins.get("imitator", spec.imitator.name).build(
        resolved.params.get("imitator"), skeleton=skeleton, checkpoint=target.imitator_checkpoint, device=device
    )
    latent, label, policy = None, "policy_output", imitator
    if use_latent and target.latent_checkpoint is not None:
        latent = plugins.get("latent", spec.latent.name).build(
            resolved.params.get("latent"), skeleton=skeleton, checkpoint=target.latent_checkpoint, device=device
        )
        check_latent_loaded(latent, Path(target.latent_checkpoint), spec.latent.name)
        label = str(load_latent_state(target.latent_checkpoint)["extra"].get("label", "policy_output"))
        policy = latent_imitator(PDTargetTeacher(imitator) if label == "pd_targets" else imitator, latent)
    return LoadedTarget(target, skeleton, lib, imitator, latent, label, policy, make_sim)


__all__ = ["EvalTarget", "LoadedTarget", "build_evaluation_target", "check_trained_humanoid", "load_evaluation_target", "motion_source_by_name"]
