"""Bad input everywhere gets one clear ``error:`` line (exit code 2) and loses nothing (issue 11).

Where each case is covered:

1. spec errors (YAML syntax, unknown names, wrong types, ``--set``, ``extends:`` loops): tests/test_spec.py,
   tests/test_specs.py and tests/test_cli.py (``test_validate_*``); not repeated here;
2. a checkpoint for another humanoid / architecture: ``test_eval_amp_checkpoint_with_smpl_spec_names_both_sides``,
   ``test_phc_checkpoint_for_another_humanoid_names_both_sides`` (imitator family),
   ``test_eval_latent_with_another_latent_dim_names_both_sides`` (pulse, via the CLI) and
   ``test_latent_plugins_raise_user_errors_on_mismatch`` (hybrid_rvq, vmp);
3. a future format version / a corrupt or truncated checkpoint: ``test_future_policy_format_version_names_both_versions``,
   ``test_corrupt_or_truncated_checkpoint_names_the_file``, ``test_truncated_checkpoint_named_by_a_spec``;
4. a missing or corrupt motion file: ``test_missing_or_corrupt_motion_file_names_it`` (+ the loaders' own
   cases in tests/test_motion.py), ``test_future_clip_format_version``;
5. missing ``pybullet_data``: ``test_missing_pybullet_data_says_what_to_install``;
6. an unwritable ``--out``: ``test_run_out_that_is_a_file_fails_before_training``,
   ``test_run_out_in_read_only_folder_fails_before_training`` (and ``mocap export`` to a file:
   ``test_export_to_a_file_or_a_full_disk_is_one_line``);
7. a full disk while writing a checkpoint: ``test_disk_full_keeps_previous_checkpoint``,
   ``test_run_on_full_disk_is_one_line_and_resumable``, ``test_export_to_a_file_or_a_full_disk_is_one_line``;
8. a plugin that fails to import: ``test_broken_plugin_is_one_warning_and_cli_still_works`` (loader-level in
   tests/test_registry.py).
"""

from __future__ import annotations

import errno
import os
import sys
from pathlib import Path

import pytest
import torch
from mocap.checkpoint import (
    CheckpointError,
    StorageError,
    load_checkpoint,
    save_checkpoint,
)
from mocap.cli import user_errors
from mocap.interfaces import Box
from mocap.plugins import get_plugins
from mocap.rl.networks import ActorCritic, load_policy, save_policy
from mocap.testing import Result, invoke
from toy_plugins import TOY_SPEC, CountTrainer

AMP_SPEC = """\
spec_version: 1
name: bad-input
humanoid: {name: amp}
motions: {name: deepmimic, params: {clips: [walk]}}
simulator: {name: mujoco}
imitator:
  name: phc
  params: {action: residual}
  trainer: {name: ppo}
"""


def assert_one_line_error(result: Result, *fragments: str) -> str:
    """Exit code 2, one ``error:`` line on stderr containing every fragment, no traceback."""
    assert result.exit_code == 2, result.output
    assert "Traceback" not in result.output
    lines = [line for line in result.stderr.splitlines() if line.startswith("error:")]
    assert len(lines) == 1, result.stderr
    for fragment in fragments:
        assert fragment in lines[0], (fragment, lines[0])
    return lines[0]


def _amp_policy(path: Path) -> Path:
    """A tiny phc policy for ``amp`` (28 actions) with its spec embedded, as training writes it."""
    from mocap.spec import load_spec_text

    resolved = load_spec_text(AMP_SPEC, get_plugins())
    skeleton = get_plugins().get("humanoid", "amp").build({})
    phc = get_plugins().get("imitator", "phc").build(resolved.params["imitator"], skeleton=skeleton)
    model = ActorCritic(phc.observation.dim(skeleton.num_bodies), Box((skeleton.num_dofs,)), [8], [8])
    save_policy(path, model, spec_yaml=resolved.to_yaml())
    return path


@pytest.fixture(scope="module")
def amp_policy(tmp_path_factory) -> Path:
    return _amp_policy(tmp_path_factory.mktemp("policy") / "policy.pt")


# ------------------------------------------------------------------ 2. another humanoid / latent size
def test_eval_amp_checkpoint_with_smpl_spec_names_both_sides(tmp_path, amp_policy):
    spec = tmp_path / "smpl.yaml"
    spec.write_text(
        AMP_SPEC.replace("{name: amp}", "{name: smpl}")
        .replace("{name: deepmimic, params: {clips: [walk]}}", f"{{name: npz, params: {{paths: [{tmp_path / 'clips'}]}}}}")
        .replace("  trainer: {name: ppo}\n", f"  checkpoint: {amp_policy}\n")
    )
    line = assert_one_line_error(invoke(["eval", spec]), str(amp_policy), "trained for humanoid amp with 28 actions", "smpl with 69")
    assert "the spec asks for smpl" in line


def test_phc_checkpoint_for_another_humanoid_names_both_sides(amp_policy, smpl):
    """What a spec naming ``imitator.checkpoint:`` meets in ``mocap run`` (the phc factory)."""
    with pytest.raises(CheckpointError, match="trained for humanoid amp with 28 actions .*; the spec asks for smpl with 69") as exc:
        get_plugins().get("imitator", "phc").build({"action": "residual"}, skeleton=smpl, checkpoint=amp_policy)
    assert isinstance(exc.value, user_errors()) and str(amp_policy) in str(exc.value)


@pytest.mark.parametrize("args", [["--clip", "nope"], ["--reference", "moving"], ["--video-trial", "7"], ["--video-trial", "worst"], ["--planner", "teleport"]])
def test_recover_with_a_bad_reference_is_one_line(amp_policy, args):
    line = assert_one_line_error(invoke(["recover", amp_policy, "--trials", "1", "--seconds", "0.1", *args]), args[1])
    assert ("walk" in line) == (args[0] == "--clip")  # an unknown clip lists the clips there are


@pytest.mark.parametrize("planner", ["getup", "getup-pose"])
def test_recover_with_the_getup_planner_on_a_motion_set_without_getups_is_one_line(amp_policy, planner):
    """The planner needs get-up clips (and a looping walk); a policy trained on walk alone has none."""
    result = invoke(["recover", amp_policy, "--trials", "1", "--seconds", "0.1", "--planner", planner])
    assert_one_line_error(result, str(amp_policy), f"--planner {planner}:", "no clip matches ['getup*']")


PULSE_SMALL = {"encoder_hidden": [8], "prior_hidden": [8], "decoder_hidden": [8]}


def test_run_with_getup_starts_on_a_motion_set_without_getups_is_one_line(tmp_path):
    """``getup_starts`` whose patterns match no clip: one error line, not a stage traceback."""
    spec = tmp_path / "spec.yaml"
    spec.write_text(
        AMP_SPEC.replace(
            "params: {action: residual}", "params: {action: residual, fail_states: {fall_init_prob: 0.5}, getup_starts: {clips: ['getup*']}}"
        ).replace("trainer: {name: ppo}", "trainer: {name: ppo, params: {num_envs: 2, horizon: 8, total_env_steps: 16, minibatch_size: 8}}")
    )
    assert_one_line_error(invoke(["run", spec, "--out", tmp_path / "runs"]), "getup_starts", "no clip matches ['getup*']")


def test_eval_latent_with_another_latent_dim_names_both_sides(tmp_path, amp_policy, amp):
    from mocap.distill_files import save_latent

    latent = get_plugins().get("latent", "pulse").build({**PULSE_SMALL, "latent_dim": 4}, skeleton=amp)
    save_latent(tmp_path / "latent.pt", latent)
    spec = tmp_path / "latent.yaml"
    spec.write_text(
        AMP_SPEC.replace("  trainer: {name: ppo}\n", f"  checkpoint: {amp_policy}\n")
        + f"latent:\n  name: pulse\n  params: {{latent_dim: 5, encoder_hidden: [8], prior_hidden: [8], decoder_hidden: [8]}}\n"
        f"  checkpoint: {tmp_path / 'latent.pt'}\n"
    )
    assert_one_line_error(invoke(["eval", spec]), str(tmp_path / "latent.pt"), "latent_dim: checkpoint 4 vs spec 5")


def test_latent_plugins_raise_user_errors_on_mismatch(tmp_path, amp):
    """hybrid_rvq and vmp: an architecture mismatch is a CheckpointError (one line in the CLI) naming both sides."""
    from mocap_hybrid_rvq.model import HybridParams, make_hybrid, save_hybrid
    from mocap_vmp.latent import VmpParams, make_vmp

    tiny = {"latent_dim": 4, "num_codes": 8, "num_quantizers": 2, "encoder_hidden": [8], "prior_hidden": [8], "decoder_hidden": [8]}
    tiny = {k: v for k, v in tiny.items() if k in HybridParams.model_fields}
    save_hybrid(tmp_path / "hybrid.pt", make_hybrid(HybridParams(**tiny), skeleton=amp))
    with pytest.raises(CheckpointError, match="latent_dim: spec 5, checkpoint 4") as exc:
        make_hybrid(HybridParams(**{**tiny, "latent_dim": 5}), skeleton=amp, checkpoint=tmp_path / "hybrid.pt")
    assert isinstance(exc.value, user_errors())

    vmp = make_vmp(VmpParams(latent_dim=4), skeleton=amp)
    save_checkpoint(tmp_path / "vmp.pt", {"latent": vmp.state_dict(), "config": vmp.config})
    with pytest.raises(CheckpointError, match="latent_dim: checkpoint 4 vs spec 6"):
        make_vmp(VmpParams(latent_dim=6), skeleton=amp, checkpoint=tmp_path / "vmp.pt")


# ------------------------------------------------------------- 3. format versions, corrupt checkpoints
def test_future_policy_format_version_names_both_versions(tmp_path, amp_policy):
    data = load_checkpoint(amp_policy)
    data["format"] = "mocap.rl.policy/7"
    data["versions"] = {**data["versions"], "mocap": "9.1.0"}
    future = tmp_path / "policy.pt"
    torch.save(data, future)
    with pytest.raises(CheckpointError, match=r"format version 7 .*mocap 9\.1\.0.* reads version 1 .*upgrade mocap"):
        load_policy(future)
    assert_one_line_error(invoke(["eval", future]), str(future), "format version 7", "reads version 1", "written by mocap 9.1.0")
    data["format"] = "someone_else.weights/1"  # not ours at all: both formats named
    torch.save(data, future)
    assert_one_line_error(invoke(["eval", future]), str(future), "not a policy file", "'someone_else.weights/1'", "'mocap.rl.policy/1'")


@pytest.mark.parametrize("damage", ["empty", "half", "garbage"])
def test_corrupt_or_truncated_checkpoint_names_the_file(tmp_path, amp_policy, damage):
    raw = amp_policy.read_bytes()
    bad = tmp_path / "policy.pt"
    bad.write_bytes({"empty": b"", "half": raw[: len(raw) // 2], "garbage": b"\x80\x04not a pickle" * 10}[damage])
    with pytest.raises(CheckpointError, match="corrupt or truncated"):
        load_policy(bad)
    assert_one_line_error(invoke(["eval", bad]), str(bad), "unreadable checkpoint", "corrupt or truncated")


def test_truncated_checkpoint_named_by_a_spec(tmp_path, amp_policy):
    bad = tmp_path / "cut.pt"
    bad.write_bytes(amp_policy.read_bytes()[:100])
    spec = tmp_path / "spec.yaml"
    spec.write_text(AMP_SPEC.replace("  trainer: {name: ppo}\n", f"  checkpoint: {bad}\n"))
    assert_one_line_error(invoke(["eval", spec]), str(bad), "corrupt or truncated")


# ----------------------------------------------------------------------------- 4. motion files
@pytest.mark.parametrize("case", ["npz_missing", "npz_truncated", "deepmimic_json"])
def test_missing_or_corrupt_motion_file_names_it(tmp_path, case):
    if case == "npz_missing":
        path, args = tmp_path / "missing.npz", ["--source", "npz"]
        expect = "no such file"
    elif case == "npz_truncated":
        path, args = tmp_path / "cut.npz", ["--source", "npz"]
        path.write_bytes(b"PK\x03\x04 truncated")
        expect = "unreadable or truncated"
    else:
        path, args = tmp_path / "humanoid3d_broken.txt", ["--source", "deepmimic"]
        path.write_text('{"Loop": "wrap", "Frames": [[0.1, ')
        expect = "not valid JSON"
    flag = "--clip" if case == "deepmimic_json" else "--path"
    assert_one_line_error(invoke(["motions", "list", *args, flag, path]), f"{path}: {expect}")


def test_future_clip_format_version(tmp_path, amp):
    import numpy as np
    from mocap.motion.clip import Clip, MotionDataError

    T, identity = 3, [1.0, 0.0, 0.0, 0.0]
    clip = Clip("still", "amp", 30.0, np.tile([0.0, 0.0, 0.9], (T, 1)), np.tile(identity, (T, 1)), np.tile(identity, (T, amp.num_bodies - 1, 1)))
    clip.save(tmp_path / "still.npz")
    with np.load(tmp_path / "still.npz") as data:
        fields = {k: data[k] for k in data.files}
    np.savez(tmp_path / "still.npz", **{**fields, "version": np.array(3)})
    with pytest.raises(MotionDataError, match=r"still\.npz: clip format version 3, but this mocap reads version 1; .*upgrade"):
        Clip.load(tmp_path / "still.npz")


# ---------------------------------------------------------------------------- 5. no pybullet_data
def test_missing_pybullet_data_says_what_to_install(monkeypatch, tmp_path):
    from mocap.motion.clip import MotionDataError
    from mocap.motion.deepmimic import DeepMimicParams, DeepMimicSource

    monkeypatch.setitem(sys.modules, "pybullet_data", None)  # `import pybullet_data` now fails, as when it is absent
    with pytest.raises(MotionDataError, match="pybullet_data.*pip install pybullet"):
        DeepMimicSource(DeepMimicParams()).files()
    assert_one_line_error(invoke(["motions", "list"]), "pybullet", "pip install pybullet")
    spec = tmp_path / "spec.yaml"
    spec.write_text(AMP_SPEC.replace("  trainer: {name: ppo}\n", f"  checkpoint: {tmp_path / 'p.pt'}\n"))
    save_policy(tmp_path / "p.pt", ActorCritic(4, Box((28,)), [4], [4]))
    assert_one_line_error(invoke(["eval", spec]), "pip install pybullet")


# ------------------------------------------------------------------------------ 6. unwritable --out
@pytest.fixture
def toy_spec(toy_plugins, tmp_path) -> Path:
    path = tmp_path / "toy.yaml"
    path.write_text(TOY_SPEC)
    return path


@pytest.mark.parametrize("where", ["file", "under_a_file"])
def test_run_out_that_is_a_file_fails_before_training(toy_spec, tmp_path, where):
    blocker = tmp_path / "taken"
    blocker.write_text("not a folder")
    out = blocker if where == "file" else blocker / "run"
    assert_one_line_error(invoke(["run", toy_spec, "--out", out]), f"--out {out}", "a file, not a directory")
    assert CountTrainer.calls == [] and blocker.read_text() == "not a folder"


def test_run_out_in_read_only_folder_fails_before_training(toy_spec, tmp_path, monkeypatch):
    locked = tmp_path / "locked"
    locked.mkdir()
    locked.chmod(0o500)
    try:
        if os.geteuid() == 0:  # root writes anywhere: make the folder refuse writes as it would for a user
            import tempfile

            real = tempfile.TemporaryFile

            def refuse(*args, dir=None, **kwargs):
                if dir is not None and Path(dir).is_relative_to(locked):
                    raise PermissionError(errno.EACCES, "Permission denied")
                return real(*args, dir=dir, **kwargs)

            monkeypatch.setattr(tempfile, "TemporaryFile", refuse)
        out = locked / "run"
        assert_one_line_error(invoke(["run", toy_spec, "--out", out]), "not writable", "Permission denied")
        assert CountTrainer.calls == []
    finally:
        locked.chmod(0o700)


def _finished_run(tmp_path: Path, policy: Path) -> Path:
    run = tmp_path / "run"
    run.mkdir()
    (run / "spec.yaml").write_text(AMP_SPEC)
    (run / "stages.json").write_text(f'[{{"stage": "imitator", "key": "k", "checkpoint": "{policy}"}}]')
    return run


def test_export_to_a_file_or_a_full_disk_is_one_line(tmp_path, amp_policy, monkeypatch):
    run = _finished_run(tmp_path, amp_policy)
    taken = tmp_path / "taken"
    taken.write_text("x")
    assert_one_line_error(invoke(["export", run, taken]), f"DEST {taken}", "a file, not a directory")
    dest = tmp_path / "ck"
    _fill_disk_after(monkeypatch, 0)
    assert_one_line_error(invoke(["export", run, dest]), str(dest / "policy.pt"), "the disk is full")
    assert list(dest.iterdir()) == []  # no half-copied policy, no temporary
    monkeypatch.undo()
    assert invoke(["export", run, dest]).exit_code == 0
    assert (dest / "policy.pt").read_bytes() == amp_policy.read_bytes()


# -------------------------------------------------------------------------------- 7. disk full
def _fill_disk_after(monkeypatch, writes_ok: int, name: str | None = None) -> list[Path]:
    """From the ``writes_ok + 1``-th atomic write (of files called ``name``) on, half the bytes reach the
    temporary file and then the write fails with ENOSPC, as on a full disk."""
    import mocap.checkpoint as ck

    real, seen, failed = ck._write_fd, [0], []

    def write(fd: int, data: bytes, path: Path) -> None:
        if name is None or path.name == name:
            seen[0] += 1
            if seen[0] > writes_ok:
                os.write(fd, data[: len(data) // 2])
                os.close(fd)
                failed.append(path)
                raise OSError(errno.ENOSPC, os.strerror(errno.ENOSPC))
        real(fd, data, path)

    monkeypatch.setattr(ck, "_write_fd", write)
    return failed


def test_disk_full_keeps_previous_checkpoint(tmp_path, monkeypatch):
    path = tmp_path / "ppo.pt"
    save_checkpoint(path, {"iteration": 1, "weights": torch.arange(1000.0)})
    before = path.read_bytes()
    _fill_disk_after(monkeypatch, 0)
    with pytest.raises(StorageError) as exc:
        save_checkpoint(path, {"iteration": 2, "weights": torch.zeros(1000)})
    message = str(exc.value)
    assert str(path) in message and "disk is full" in message and "previous ppo.pt is unchanged" in message
    assert exc.value.errno == errno.ENOSPC and isinstance(exc.value, user_errors())
    assert path.read_bytes() == before and load_checkpoint(path)["iteration"] == 1
    assert sorted(p.name for p in tmp_path.iterdir()) == ["ppo.pt"]  # no temporary left behind


def test_run_on_full_disk_is_one_line_and_resumable(toy_spec, tmp_path, monkeypatch):
    out = tmp_path / "runs" / "toy"
    failed = _fill_disk_after(monkeypatch, 1, name="checkpoint.pt")  # iteration 1 is saved, iteration 2 is not
    assert_one_line_error(invoke(["run", toy_spec, "--out", out]), "checkpoint.pt", "the disk is full", "is unchanged")
    (ckpt,) = failed[:1]
    assert load_checkpoint(ckpt)["iteration"] == 1
    assert not list(ckpt.parent.glob(".*.tmp"))
    monkeypatch.undo()  # space freed: the same command resumes from iteration 1
    result = invoke(["run", toy_spec, "--out", out])
    assert result.exit_code == 0, result.output
    assert load_checkpoint(ckpt)["iteration"] == 3


# ------------------------------------------------------------------------ 8. a plugin that fails
def test_broken_plugin_is_one_warning_and_cli_still_works(monkeypatch):
    from importlib import metadata

    import mocap.plugins as plugins_module
    from mocap.plugins import load_plugins, set_plugins

    real = metadata.entry_points

    def with_broken(group=None, **kw):
        eps = list(real(group=group, **kw)) if group else []
        return [*eps, metadata.EntryPoint(name="half_installed", value="mocap_half_installed_xyz", group="mocap")]

    monkeypatch.setattr(plugins_module.metadata, "entry_points", with_broken)
    broken = load_plugins()
    monkeypatch.undo()
    previous = get_plugins()
    set_plugins(broken)  # the installed plugins plus an entry point whose module is gone
    try:
        result = invoke(["plugins", "--json"])
    finally:
        set_plugins(previous)
    assert result.exit_code == 0, result.output
    warnings = [line for line in result.stderr.splitlines() if "half_installed" in line]
    assert len(warnings) == 1 and warnings[0].startswith("warning:") and "mocap_half_installed_xyz" in warnings[0]
    assert '"sim_mujoco"' in result.stdout


def test_a_teacher_whose_observation_the_latent_cannot_read_is_one_error_line(tmp_path, capsys):
    """Distilling from an imitator with another observation (pd_replay's raw state, 28 dims) was a
    traceback; it is one line naming both sizes and what a teacher must be."""
    from mocap.cli import main

    spec = tmp_path / "spec.yaml"
    spec.write_text(
        "spec_version: 1\nname: pdrep-distill\nmotions: {name: deepmimic, params: {clips: [walk]}}\nimitator: {name: pd_replay}\n"
        "latent:\n  name: pulse\n  params: {latent_dim: 4, encoder_hidden: [8], prior_hidden: [8], decoder_hidden: [8]}\n"
        "  trainer: {name: distill, params: {num_envs: 2, horizon: 4, total_env_steps: 16, minibatch_envs: 2, eval_every: 0}}\n"
    )
    assert main(["run", str(spec), "--out", str(tmp_path / "runs" / "x")]) == 2
    err = capsys.readouterr().err
    assert "cannot read the teacher's observation" in err and "Traceback" not in err
