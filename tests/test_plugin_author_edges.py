"""What a plugin author meets at the edges (issue 66 items 2-5): the conformance example of
``docs/plugins.md`` runs verbatim, every contract failure says what to do, a resumed task without
state is warned about at once, and ``mocap task-eval`` shows display names and units."""

from __future__ import annotations

import re
from pathlib import Path

import pytest
import torch
from test_distill import walk  # noqa: F401  (fixture)
from test_hierarchy import Upright, UprightParams, _env

from mocap.generation import GenerationParams
from mocap.generation_eval import evaluate_generation
from mocap.hierarchy import ScratchParams
from mocap.metric_display import MetricInfo
from mocap.plugins import get_plugins
from mocap.state import Observations
from mocap.task_env import ScratchLatent, TaskEnv, stateless_task_warning
from mocap.task_eval import render_task_eval
from mocap.testing import ContractViolation, check_latent_space, check_task, fake_sim_state

DOCS = Path(__file__).resolve().parents[1] / "docs" / "plugins.md"


def test_the_conformance_example_of_the_plugin_docs_runs_verbatim(capsys: pytest.CaptureFixture[str]) -> None:
    blocks = re.findall(r"```python\n(.*?)```", DOCS.read_text(encoding="utf-8"), flags=re.S)
    example = [b for b in blocks if "check_latent_space" in b and "check_task" in b]
    assert len(example) == 1, "docs/plugins.md has one conformance example"
    exec(compile(example[0], str(DOCS), "exec"), {"__name__": "docs_example"})
    out = capsys.readouterr().out
    assert "state_dict round-trip" in out and "task state round-trip" in out


def test_a_task_that_forgets_its_goals_is_told_what_to_add(amp) -> None:  # type: ignore[no-untyped-def]
    task = get_plugins().get("task", "speed").build(None, skeleton=amp, num_envs=4, device="cpu")
    task.load_state_dict = lambda state: None  # type: ignore[method-assign]
    with pytest.raises(ContractViolation, match=r"does not restore the goals: return every per-env goal.*Task.state_dict\(\).*docs/plugins.md"):
        check_task(task, amp, num_envs=4)


def test_resuming_a_task_without_state_warns_at_once(amp, walk) -> None:  # type: ignore[no-untyped-def]  # noqa: F811
    assert stateless_task_warning(get_plugins().get("task", "speed").build(None, skeleton=amp, num_envs=2, device="cpu")) is None
    message = stateless_task_warning(Upright(UprightParams(), 2))
    assert message is not None and "Upright" in message and "state_dict()" in message and "docs/plugins.md" in message
    env = _env(amp, walk, ScratchLatent(ScratchParams(), amp))
    try:
        env.reset()
        saved = env.state_dict()
        with pytest.warns(RuntimeWarning, match="resuming task Upright, which defines no state_dict"):
            env.load_state_dict(saved)
    finally:
        env.close()


class PriorWithoutFlag(ScratchLatent):
    """Samples something but forgot ``samples_prior = True``."""

    def random_action(self, obs: Observations, noise_scale: float = 1.0, generator: torch.Generator | None = None) -> torch.Tensor:
        return torch.zeros(obs.proprio.shape[0], self.latent_dim)


def test_random_action_without_samples_prior_is_named_with_the_flag_to_set(amp) -> None:  # type: ignore[no-untyped-def]
    from mocap.observations import proprioception_and_goal

    latent = PriorWithoutFlag(ScratchParams(), amp)
    proprio, goal = proprioception_and_goal(fake_sim_state(amp, 3), fake_sim_state(amp, 3, seed=1))
    with pytest.raises(ContractViolation, match="defines random_action but leaves samples_prior False.*samples_prior = True"):
        check_latent_space(latent, Observations(proprio=proprio.float(), goal=goal.float()), amp.num_dofs)
    with pytest.raises(ValueError, match=r"cannot generate: it has no prior to sample.*set.*samples_prior = True.*docs/plugins.md"):
        evaluate_generation(latent, None, lambda obs, out: out, None, lambda n: None, GenerationParams())  # type: ignore[arg-type]


def test_task_eval_table_shows_display_names_and_units() -> None:
    result = {"task": "speed", "latent": "pulse", "protocol": "p", "speed_error": 1.25, "episode_length": 300.0, "mystery": 2.0, "seed": 0}
    table = render_task_eval(result, {"speed_error": MetricInfo("speed error", "m/s")})
    assert "| speed error (m/s) | `speed_error` | 1.25 |" in table
    assert "| episode length (ended episodes) (control steps) | `episode_length` | 300 |" in table
    assert "| mystery | `mystery` | 2 |" in table  # undeclared: the key itself
    # the installed tasks' declarations by default
    assert "speed error (m/s)" in render_task_eval(result)


def test_a_task_env_uses_its_teachers_proprioception_layout(tmp_path: Path) -> None:
    """Issue 60 item 4: the task env observes proprioception in the 6D layout of the imitator the latent
    space was distilled from (``Imitator.proprio_sixd``); a ``tan_norm`` teacher (PHC's SMPL recipe)
    got ``zhou`` features before."""
    import io

    from rich.console import Console

    from mocap.observations import proprioception
    from mocap.pipeline import StageContext
    from mocap.runlog import MetricsLogger
    from mocap.spec import load_spec_text
    from mocap.task_env import make_task_env

    text = """
spec_version: 1
name: sixd
humanoid: {name: amp}
motions: {name: deepmimic, params: {clips: [walk]}}
simulator: {name: mujoco}
imitator: {name: phc, params: {sixd: tan_norm}, trainer: {name: ppo}}
latent: {name: scratch}
task: {name: speed, trainer: {name: ppo}}
"""
    plugins = get_plugins()
    resolved = load_spec_text(text, plugins)
    log = MetricsLogger(tmp_path / "metrics.jsonl", "task")
    ctx = StageContext("task", resolved, plugins, tmp_path, tmp_path, {}, log, 0, torch.device("cpu"), Console(file=io.StringIO()))
    env = make_task_env(ctx, 2)
    try:
        obs = env.reset()
        assert env.sixd == "tan_norm"
        expect = proprioception(env.sim.state, "tan_norm").float()
        assert torch.allclose(obs[:, : expect.shape[1]], expect, atol=1e-5)
        assert not torch.allclose(expect, proprioception(env.sim.state, "zhou").float(), atol=1e-3)
    finally:
        env.close()
        log.close()


def test_a_factorys_own_type_error_is_not_hidden_behind_not_rl_trainable(tmp_path: Path) -> None:
    """Issue 60 item 4: no ``except TypeError`` control flow in ``StageContext.make_rl_env``: a bug
    inside an imitator's factory surfaces as itself."""
    import io
    import types

    from rich.console import Console

    from mocap.hooks import hookimpl
    from mocap.pipeline import StageContext
    from mocap.plugins import load_plugins
    from mocap.runlog import MetricsLogger
    from mocap.spec import load_spec_text

    def broken(*, skeleton, checkpoint=None, device="cpu"):  # type: ignore[no-untyped-def]  (no params model: called without params)
        raise TypeError("the author's own bug")

    plugin = types.SimpleNamespace(register_imitators=hookimpl(lambda register: register("broken_imitator", broken)))
    plugins = load_plugins([("broken", plugin)])
    text = (
        "spec_version: 1\nname: b\nhumanoid: {name: amp}\nmotions: {name: deepmimic}\nsimulator: {name: mujoco}\n"
        "imitator: {name: broken_imitator, trainer: {name: ppo}}\n"
    )
    log = MetricsLogger(tmp_path / "metrics.jsonl", "imitator")
    ctx = StageContext("imitator", load_spec_text(text, plugins), plugins, tmp_path, tmp_path, {}, log, 0, torch.device("cpu"), Console(file=io.StringIO()))
    with pytest.raises(TypeError, match="the author's own bug"):
        ctx.make_rl_env(2)
    log.close()


@pytest.mark.parametrize("task_name", ["speed", "reach", "strike"])
def test_the_official_codes_start_protocol_draws_run_frames_facing_x_or_at_the_origin(amp, task_name: str, monkeypatch) -> None:  # type: ignore[no-untyped-def]
    """Issue 65 item 1: ``start: {clips: [run], face_x: true}`` (speed) or ``{clips: [run], origin: true}``
    (reach, strike) as PULSE's code starts its task commands; the default keeps today's starts."""
    import mocap.generation_eval as generation_eval
    from mocap.motion.library import MotionLibrary
    from mocap.rotations import heading_angle
    from mocap.state import MotionFrames

    task_c = get_plugins().get("task", task_name)
    start = {"clips": ["run"], "face_x": True} if task_name == "speed" else {"clips": ["run"], "origin": True}
    task = task_c.build(task_c.validate_params({"start": start}), skeleton=amp, num_envs=6, device="cpu")
    assert tuple(task.start_clips) == ("run",)
    lib = MotionLibrary(get_plugins().get("motion_source", "deepmimic").build(None).load(amp), amp)
    seen: list = []
    real = generation_eval.start_states

    def spy(lib, n, skeleton, min_height, generator, clips=None):  # type: ignore[no-untyped-def]
        seen.append(clips)
        return real(lib, n, skeleton, min_height, generator, clips)

    monkeypatch.setattr(generation_eval, "start_states", spy)
    sim_c = get_plugins().get("simulator", "mujoco")
    sim = sim_c.build(sim_c.validate_params(dict(task.sim_overrides)), skeleton=amp, num_envs=6, seed=0)
    env = TaskEnv(task, ScratchLatent(ScratchParams(), amp), lambda obs, out: out, lib, sim, seed=1)
    try:
        env.reset()  # the task env draws the start frames from the task's start clips
    finally:
        env.close()
    assert seen == [["run"]]
    ids, times = real(lib, 6, amp, 0.25, torch.Generator().manual_seed(0), ["run"])
    assert set(ids.tolist()) == {lib.clip_index("run")}
    frames = lib.frames(ids, times)
    placed = task.start_state(torch.arange(6), frames)
    assert isinstance(placed, MotionFrames) and torch.equal(placed.dof_pos, frames.dof_pos)
    if task_name == "speed":
        assert float(heading_angle(placed.root_rot).abs().max()) < 1e-5
        assert torch.allclose(placed.root_pos, frames.root_pos, atol=1e-6)  # turned in place
    else:
        assert float(placed.root_pos[:, :2].abs().max()) < 1e-6 and torch.allclose(placed.root_pos[:, 2], frames.root_pos[:, 2])
    default = task_c.build(None, skeleton=amp, num_envs=6, device="cpu")
    assert default.start_clips is None and default.start_state(torch.arange(6), frames) is frames
