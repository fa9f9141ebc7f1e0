"""Pipeline: stage order, artifact keys (stable, sensitive), reuse across specs, resume after Ctrl-C."""

from __future__ import annotations

import json
from pathlib import Path

import pytest
from rich.console import Console
from toy_plugins import TOY_SPEC, CountTrainer, toy

from mocap.checkpoint import save_checkpoint
from mocap.pipeline import PipelineInterrupted, resolved_stage_keys, run_pipeline, stage_keys
from mocap.plugins import load_plugins
from mocap.spec import load_spec_text

PSET = load_plugins([("toy", toy)], entry_points=False)


def resolve(overrides=None, text=TOY_SPEC):
    return load_spec_text(text, PSET, overrides=overrides)


def quiet() -> Console:
    return Console(file=open("/dev/null", "w"))


def test_same_spec_same_keys_and_any_relevant_change_new_keys():
    base = stage_keys(resolve().spec)
    assert set(base) == {"imitator", "latent"}
    assert stage_keys(resolve().spec) == base
    # a change in the latent section changes only the latent key
    k = stage_keys(resolve(["latent.params.hidden=9"]).spec)
    assert k["imitator"] == base["imitator"] and k["latent"] != base["latent"]
    # a change upstream (imitator) or in the shared context changes both
    for change in (["imitator.params.optim.lr=0.5"], ["imitator.trainer.params.iterations=4"], ["seed=1"], ["simulator.params.hidden=5"]):
        k = stage_keys(resolve(change).spec)
        assert k["imitator"] != base["imitator"] and k["latent"] != base["latent"], change
    # names and descriptions are not part of any stage
    assert stage_keys(resolve(["name=other", "description=x"]).spec) == base
    # writing a default explicitly is the same spec
    assert stage_keys(resolve(["latent.params.hidden=8"]).spec) == base


def test_run_writes_run_dir_and_second_spec_reuses_shared_imitator(tmp_path: Path):
    CountTrainer.calls.clear()
    out = tmp_path / "runs" / "a"
    records = run_pipeline(resolve(), PSET, out, console=quiet())
    assert [r.stage for r in records] == ["imitator", "latent"] and not any(r.reused for r in records)
    assert CountTrainer.calls == ["imitator", "latent"]
    for name in ("spec.yaml", "metrics.jsonl", "report.md", "stages.json"):
        assert (out / name).is_file(), name
    lines = [json.loads(l) for l in (out / "metrics.jsonl").read_text().splitlines()]
    assert [(l["stage"], l["step"]) for l in lines] == [("imitator", 1), ("imitator", 2), ("imitator", 3), ("latent", 1), ("latent", 2)]
    assert list((out / "tb").iterdir())
    # the latent trainer saw the imitator's result
    assert records[1].result.metrics == {"iterations": 2.0}

    CountTrainer.calls.clear()
    out_b = tmp_path / "runs" / "b"
    records_b = run_pipeline(resolve(["latent.name=toy_latent_b"]), PSET, out_b, console=quiet())
    assert records_b[0].reused and not records_b[1].reused
    assert CountTrainer.calls == ["latent"]
    assert records_b[0].workdir == records[0].workdir
    assert "reused" in (out_b / "stages.json").read_text()
    # what the reused stage published (tables, videos) is in the new run directory too
    assert (out_b / "imitator_count.txt").read_text() == "3" and (out / "imitator_count.txt").is_file()
    assert "[imitator_count.txt]" not in (out_b / "report.md").read_text()  # only media are linked


def test_interrupt_then_rerun_resumes_and_finishes(tmp_path: Path):
    CountTrainer.calls.clear()
    out = tmp_path / "runs" / "x"
    spec = resolve(["imitator.trainer.params.stop_after=2", "imitator.trainer.params.iterations=5"])
    # stop_after is part of the trainer params, hence of the key; emulate the user re-running
    # the same command by reusing the same resolved spec after the interruption.
    with pytest.raises(PipelineInterrupted):
        run_pipeline(spec, PSET, out, console=quiet())
    keys = resolved_stage_keys(spec, PSET)
    workdir = tmp_path / "runs" / "artifacts" / f"imitator-{keys['imitator']}"
    assert (workdir / "checkpoint.pt").is_file() and not (workdir / "DONE.json").exists()
    with pytest.raises(PipelineInterrupted):  # resumes at 2, runs 3 and 4, interrupted again
        run_pipeline(spec, PSET, out, console=quiet())
    records = run_pipeline(spec, PSET, out, console=quiet())
    assert records[0].result.metrics["iterations"] == 5.0
    steps = [json.loads(l)["step"] for l in (out / "metrics.jsonl").read_text().splitlines() if '"imitator"' in l]
    assert steps == [1, 2, 3, 4, 5]


def test_stage_with_checkpoint_is_not_trained_and_keyed_by_content(tmp_path: Path):
    ckpt = tmp_path / "imitator.pt"
    save_checkpoint(ckpt, {"weights": [1, 2, 3]})
    text = TOY_SPEC.replace("  trainer: {name: count, params: {iterations: 3}}", f"  checkpoint: {ckpt}")
    CountTrainer.calls.clear()
    records = run_pipeline(resolve(text=text), PSET, tmp_path / "runs" / "c", console=quiet())
    assert CountTrainer.calls == ["latent"] and records[0].result.checkpoint == ckpt
    key1 = stage_keys(resolve(text=text).spec)["imitator"]
    save_checkpoint(ckpt, {"weights": [1, 2, 4]})
    assert stage_keys(resolve(text=text).spec)["imitator"] != key1


def test_a_second_run_into_a_busy_run_directory_is_refused(tmp_path: Path):
    """Two runs into one directory would interleave metrics.jsonl: the second is refused at once."""
    from mocap.pipeline import StageFailed, run_dir_lock

    out = tmp_path / "runs" / "a"
    out.mkdir(parents=True)
    with run_dir_lock(out):
        with pytest.raises(StageFailed, match=r"another mocap run \(pid \d+\) is writing to this run directory"):
            run_pipeline(resolve(), PSET, out, console=quiet())
        assert not (out / "metrics.jsonl").exists()
    run_pipeline(resolve(), PSET, out, console=quiet())  # released: the run goes ahead
    assert (out / "report.md").is_file()


def test_rows_of_a_stage_attempt_killed_before_its_checkpoint_are_not_kept(tmp_path: Path):
    """A stage killed after logging but before its first checkpoint (an eval stage always is) reruns
    from scratch: its earlier rows go, so none is duplicated."""
    out = tmp_path / "runs" / "a"
    out.mkdir(parents=True)
    stale = [{"stage": "imitator", "step": 1, "value": 99.0}, {"stage": "imitator", "step": 2, "value": 99.0}]
    (out / "metrics.jsonl").write_text("".join(json.dumps(r) + "\n" for r in stale))
    run_pipeline(resolve(), PSET, out, console=quiet())
    rows = [json.loads(line) for line in (out / "metrics.jsonl").read_text().splitlines()]
    steps = [(r["stage"], r["step"]) for r in rows]
    assert steps == [("imitator", 1), ("imitator", 2), ("imitator", 3), ("latent", 1), ("latent", 2)]
    assert all(r["value"] != 99.0 for r in rows)


def test_rerunning_a_finished_spec_keeps_the_original_training_times(tmp_path: Path):
    """A rerun that reuses every stage reports their original training time, not 0.0 s."""
    import re

    out = tmp_path / "runs" / "a"
    first = run_pipeline(resolve(), PSET, out, console=quiet())
    trained = {r.stage: r.seconds for r in first}
    again = run_pipeline(resolve(), PSET, out, console=quiet())
    assert all(r.reused for r in again)
    for r in again:
        assert r.trained_seconds == pytest.approx(trained[r.stage], abs=0.02)
    report = (out / "report.md").read_text()
    assert re.search(r"2 stages reused from earlier runs; their training took \d+\.\d s", report)
    stages = json.loads((out / "stages.json").read_text())
    assert all(s["trained_seconds"] is not None for s in stages)


def test_a_stage_that_fails_before_any_output_leaves_no_empty_artifact_folder(tmp_path: Path, monkeypatch):
    def boom(self, ctx):
        raise RuntimeError("trainer bug")

    monkeypatch.setattr(CountTrainer, "run", boom)
    out = tmp_path / "runs" / "a"
    with pytest.raises(RuntimeError, match="trainer bug"):
        run_pipeline(resolve(), PSET, out, console=quiet())
    store = tmp_path / "runs" / "artifacts"
    assert not [p for p in store.iterdir() if p.is_dir()], list(store.iterdir())


def test_editing_a_motion_file_in_place_changes_every_trained_stage_key(tmp_path: Path):
    """The artifact keys fingerprint the motion files, not only the spec: a clip edited in place is
    not served from a stage trained on the old clip, and the same bytes give the same keys again."""
    from mocap.motion.deepmimic import default_data_dir
    from mocap.plugins import get_plugins
    from mocap.spec import load_spec

    plugins = get_plugins()
    root = Path(__file__).resolve().parents[1]
    data = tmp_path / "motions"
    data.mkdir()
    for clip in ("walk", "run"):
        name = f"humanoid3d_{clip}.txt"
        (data / name).write_bytes((default_data_dir() / name).read_bytes())
    sets = [f"motions.params.data_dir={data}", "motions.params.clips=[walk, run]"]

    def keys() -> dict[str, str]:
        return resolved_stage_keys(load_spec(root / "specs" / "imitator" / "amp_bundled.yaml", plugins, sets), plugins)

    before = keys()
    assert keys() == before
    walk = data / "humanoid3d_walk.txt"
    walk.write_text(walk.read_text().replace('"Loop"', '"Loop" ', 1))  # one byte more, same clip semantics
    after = keys()
    assert after["imitator"] != before["imitator"] and after["eval"] != before["eval"]
    walk.write_text(walk.read_text().replace('"Loop" ', '"Loop"', 1))
    assert keys() == before  # by content, not by modification time


def test_a_misspelled_video_clip_fails_before_any_stage_trains(tmp_path: Path):
    """``eval.trainer.params.video_clip`` is checked by the eval trainer's preflight before the imitator
    trains, not hours later when the eval stage records its video."""
    from mocap.errors import UserError
    from mocap.plugins import get_plugins
    from mocap.spec import load_spec

    plugins = get_plugins()
    root = Path(__file__).resolve().parents[1]
    sets = ["motions.params.clips=[walk, run]", "eval.trainer.params.video_clip=wlak"]
    resolved = load_spec(root / "specs" / "imitator" / "amp_bundled.yaml", plugins, sets)
    with pytest.raises(UserError, match=r"video_clip: no clip 'wlak' in the motion set \(clips: walk, run\)"):
        run_pipeline(resolved, plugins, tmp_path / "runs" / "x", console=quiet())
    assert not (tmp_path / "runs" / "artifacts").exists() or not any((tmp_path / "runs" / "artifacts").iterdir())


def test_a_phase_is_a_child_context_of_its_stage(tmp_path: Path):
    """``StageContext.phase``: what PMCP and VMP run PPO / the supervised trainer in (it replaced two
    hand-made shims): own workdir, rows labelled ``<stage>/<phase>``, own env and stop condition, the
    parent's Ctrl-C, and published files still reach the stage's run directory."""
    import torch
    from rich.console import Console

    from mocap.pipeline import StageContext
    from mocap.runlog import MetricsLogger

    stopped = {"parent": False, "phase": False}
    ctx = StageContext(
        stage="latent", resolved=None, plugins=None, workdir=tmp_path / "stage", run_dir=tmp_path, upstream={},  # type: ignore[arg-type]
        log=MetricsLogger(tmp_path / "metrics.jsonl", "latent"), seed=3, device=torch.device("cpu"), console=Console(),
        _stop=lambda: stopped["parent"],
    )  # fmt: skip
    sub = ctx.phase("tracker", workdir=tmp_path / "stage" / "tracker", seed=9, env_factory=lambda n: ("env", n), stop=lambda: stopped["phase"])
    assert sub.workdir == tmp_path / "stage" / "tracker" and sub.seed == 9 and ctx.seed == 3
    assert sub.make_rl_env(4) == ("env", 4)
    sub.log.log(1, x=1.0)
    ctx.log.log(1, y=2.0)
    rows = [json.loads(line) for line in (tmp_path / "metrics.jsonl").read_text().splitlines()]
    assert [r["stage"] for r in rows] == ["latent/tracker", "latent"]
    assert not sub.should_stop()
    stopped["phase"] = True
    assert sub.should_stop() and not ctx.should_stop()
    stopped["phase"], stopped["parent"] = False, True
    assert sub.should_stop()
    assert sub.publish("t.md").parent == ctx.publish("t.md").parent
    assert sub.phase("vae", workdir=tmp_path / "v").publish("a.md").parent == ctx.publish("a.md").parent


def test_a_run_that_fails_before_any_stage_starts_leaves_the_finished_runs_record(tmp_path: Path):
    """Issue 63, newcomer 3: a failed run (a missing ``checkpoint:``) into the directory of a finished
    run must not rewrite its ``spec.yaml``, ``stages.json``, ``report.md`` or published files."""
    from mocap.pipeline import StageFailed

    out = tmp_path / "runs" / "a"
    run_pipeline(resolve(), PSET, out, console=quiet())
    # another run trains an imitator that publishes another count (which a reuse would copy)
    run_pipeline(resolve(["imitator.trainer.params.iterations=4"]), PSET, tmp_path / "runs" / "b", console=quiet())
    before = {p.name: p.read_bytes() for p in out.iterdir() if p.is_file() and p.name != ".mocap-run.lock"}
    assert {"spec.yaml", "stages.json", "report.md", "imitator_count.txt"} <= set(before)
    failing = resolve(["imitator.trainer.params.iterations=4", "latent.trainer=null", f"latent.checkpoint={tmp_path / 'nothere.pt'}"])
    with pytest.raises(StageFailed, match="nothere.pt: no such file"):
        run_pipeline(failing, PSET, out, console=quiet())
    after = {p.name: p.read_bytes() for p in out.iterdir() if p.is_file() and p.name != ".mocap-run.lock"}
    assert after == before
    # a run that does start a stage owns the directory from then on
    run_pipeline(resolve(["latent.trainer.params.iterations=3"]), PSET, out, console=quiet())
    assert "iterations: 3" in (out / "spec.yaml").read_text().split("latent:")[1]
