"""PHC+'s recovery primitive P(F) by distillation (``recovery.method: planner_distill``,
:mod:`mocap_phc.pmcp_distill`): the tiny PMCP spec of test_pmcp with a get-up clip."""

from __future__ import annotations

import io
import json
from pathlib import Path

import torch
from test_pmcp import RECOVERY_SPEC, imitator_context

from mocap.checkpoint import load_checkpoint


def distill_spec(env_steps: int, distill: str) -> str:
    """The tiny recovery spec with a get-up clip and P(F) by ``planner_distill`` (``distill``: its flow-style settings)."""
    return RECOVERY_SPEC.replace("clips: [walk, kick]}", "clips: [walk, kick, getup_faceup]}").replace(
        "recovery: {clips: [walk], env_steps: 128,",
        f"recovery: {{clips: [walk, getup], env_steps: {env_steps}, method: planner_distill, distill: {distill},",
    )


def test_pmcp_recovery_by_planner_distillation(tmp_path, amp):
    """``recovery.method: planner_distill``: P(F) is fitted (DAgger) to the previous primitive driven by
    the get-up planner, saved as a primitive, evaluated and frozen; the composer mixes K + 1."""
    from mocap.testing import invoke
    from mocap_phc.imitator import PHCParams, make_phc

    text = distill_spec(40, "{num_envs: 2, seconds: 0.5, epochs: 1, minibatch_size: 16, checkpoint_every: 1, action_noise: 0.05, fall: {settle_steps: 5}}")
    assert "planner_distill" in text and "getup_faceup" in text
    spec = tmp_path / "spec.yaml"
    spec.write_text(text)
    result = invoke(["run", spec, "--out", tmp_path / "runs" / "d"])
    assert result.exit_code == 0, result.output
    assert "P(F) distillation it 2/2" in result.output  # 40 env steps / (2 envs x 15 steps) -> 2 iterations
    final = Path(json.loads((tmp_path / "runs" / "d" / "stages.json").read_text())[0]["checkpoint"])
    prims = json.loads((final.parent / "pmcp_state.json").read_text())["primitives"]
    assert prims[1]["recovery"] is True and prims[1]["method"] == "planner_distill" and prims[1]["env_steps"] == 60
    teacher = load_checkpoint(final.parent / "prim0" / "primitive.pt")["state_dict"]
    student = load_checkpoint(final.parent / "prim1" / "primitive.pt")["state_dict"]
    moved_ = [k for k in teacher if k.startswith("actor_body") and not torch.equal(teacher[k], student[k])]
    assert moved_  # the student's actor was fitted
    assert all(torch.equal(teacher[k], student[k]) for k in teacher if k.startswith(("critic_body", "value_head")))
    imitator = make_phc(PHCParams(action="residual", recovery_goal={"form": "paper"}), skeleton=amp, checkpoint=final)
    assert imitator.num_primitives == 2


def test_planner_distillation_targets_and_schedule():
    """The student's targets reproduce the teacher's PD targets through the student's own action map."""
    from mocap_phc.pmcp_distill import student_targets, teacher_share

    q = torch.tensor([[0.5, -0.2, 4.0]])
    ref = torch.tensor([[0.1, 0.1, 0.0]])
    assert torch.allclose(student_targets(q, ref, "residual", torch.zeros(3), torch.ones(3), None), q - ref)
    assert torch.allclose(student_targets(q, ref, "residual", torch.zeros(3), torch.ones(3), 3.0), torch.tensor([[0.4, -0.3, 3.0]]))
    off, scale = torch.tensor([0.1, 0.0, 1.0]), torch.tensor([2.0, 1.0, 0.5])
    a = student_targets(q, None, "absolute", off, scale, None)
    assert torch.allclose(off + scale * a, q)
    assert [teacher_share(i, 10, 0.5) for i in (0, 1, 5, 9)] == [1.0, 0.8, 0.0, 0.0]
    assert [round(teacher_share(i, 10, 0.5, 0.5), 6) for i in (0, 1, 5, 9)] == [1.0, 0.9, 0.5, 0.5]
    assert [teacher_share(i, 10, 0.5, 1.0) for i in (0, 5, 9)] == [1.0, 1.0, 1.0]  # behaviour cloning


def test_pmcp_planner_distillation_resumes_after_a_stop(tmp_path):
    """A stop inside the distillation leaves ``distill.pt``; the rerun continues at its iteration
    (the rollout buffer starts empty, as its message says) and the stage finishes."""
    from mocap.plugins import get_plugins
    from mocap.spec import load_spec_text

    text = distill_spec(90, "{num_envs: 2, seconds: 0.5, epochs: 1, minibatch_size: 16, checkpoint_every: 5, fall: {settle_steps: 5}}")
    plugins = get_plugins()
    resolved = load_spec_text(text, plugins)
    workdir, outputs = tmp_path / "art", []
    for interrupt in (True, False):  # first: stop after P(F)'s first distillation iteration; then run to the end
        calls = {"n": 0}

        def stop(calls: dict[str, int] = calls, interrupt: bool = interrupt) -> bool:
            state_file = workdir / "pmcp_state.json"
            if state_file.is_file() and json.loads(state_file.read_text())["phase"] == "recovery":
                calls["n"] += 1  # 1: the check on entering the phase; 2: after the first distillation iteration
            return interrupt and calls["n"] >= 2

        out = io.StringIO()
        ctx, log = imitator_context(resolved, plugins, workdir, tmp_path, stop, out)
        ctx.build("imitator.trainer").run(ctx)
        log.close()
        outputs.append(out.getvalue())
        if interrupt:
            saved = load_checkpoint(workdir / "prim1" / "distill.pt")
            assert saved["iteration"] == 1 and not (workdir / "prim1" / "primitive.pt").exists()
    assert "P(F) distillation resumes at iteration 1 of 3" in outputs[1] and "distillation it 1/3" not in outputs[1]
    state = json.loads((workdir / "pmcp_state.json").read_text())
    assert state["phase"] == "done" and state["primitives"][1]["env_steps"] == 90


def test_planner_distillation_without_getup_clips_is_one_error_line(tmp_path):
    """Checked when the stage starts (not after primitive 0): one ``error:`` line, no traceback."""
    from mocap.testing import invoke

    text = RECOVERY_SPEC.replace("recovery: {clips: [walk], env_steps: 128,", "recovery: {clips: [walk], env_steps: 128, method: planner_distill,")
    assert "planner_distill" in text and "getup" not in text
    spec = tmp_path / "spec.yaml"
    spec.write_text(text)
    result = invoke(["run", spec, "--out", tmp_path / "runs" / "e"])
    assert result.exit_code == 2 and "Traceback" not in result.output
    lines = [line for line in result.stderr.splitlines() if line.startswith("error:")]
    assert len(lines) == 1 and "planner_distill" in lines[0] and "no clip matches ['getup*']" in lines[0], result.stderr
    assert "primitive 0" not in result.output  # before any training
