"""The built-in components pass the conformance checks plugin authors use (mocap.testing)."""

from __future__ import annotations

import dataclasses

import pytest
import torch

from mocap.plugins import get_plugins
from mocap.state import Observations
from mocap.testing import ContractViolation, check_latent_space, check_simulator, check_task, fake_sim_state


def test_fake_sim_state_is_consistent(amp):
    s = fake_sim_state(amp, 5, seed=3)
    assert s.body_pos.shape == (5, amp.num_bodies, 3) and torch.allclose(s.body_pos[:, 0], s.root_pos)
    assert torch.allclose(torch.linalg.vector_norm(s.body_rot, dim=-1), torch.ones(5, amp.num_bodies), atol=1e-5)
    assert torch.equal(fake_sim_state(amp, 5, seed=3).dof_pos, s.dof_pos) and not torch.equal(fake_sim_state(amp, 5, seed=4).dof_pos, s.dof_pos)


def test_mujoco_simulator_keeps_the_contract(amp):
    sim = get_plugins().get("simulator", "mujoco").build(None, skeleton=amp, num_envs=4, seed=0)
    try:
        report = check_simulator(sim)
    finally:
        sim.close()
    assert "physics state round-trip" in report
    assert "external wrench" in report and "per-env models" in report and "movable target" not in report  # built without the prop


def test_a_simulator_built_with_the_strike_target_checks_its_movable_target(amp):
    """Issue 60 item 4: the capabilities tasks use are declared (mocap.interfaces.MovableTarget, ...)
    and exercised by check_simulator; a target that does not land where it was put is named."""
    from mocap.interfaces import MovableTarget

    component = get_plugins().get("simulator", "mujoco")
    task = get_plugins().get("task", "strike").build(None, skeleton=amp, num_envs=4, device="cpu")
    sim = component.build(component.validate_params(dict(task.sim_overrides)), skeleton=amp, num_envs=4, seed=0)
    try:
        assert isinstance(sim, MovableTarget) and sim.has_target
        assert "movable target" in check_simulator(sim)
        real = sim.target_state
        sim.target_state = lambda: dataclasses.replace(real(), pos=real().pos + 1.0)  # type: ignore[method-assign]
        with pytest.raises(ContractViolation, match="not where set_target put it"):
            check_simulator(sim)
    finally:
        sim.close()


BUILTIN_TASKS = ["generation", "hmd_tracking", "inbetween", "motion_tracking", "point_goal", "reach", "speed", "strike", "terrain", "vr_tracking"]


def test_every_registered_task_is_checked():
    assert sorted(get_plugins().components["task"]) == BUILTIN_TASKS


@pytest.mark.parametrize("name", BUILTIN_TASKS)
def test_builtin_tasks_keep_the_contract_and_report_only_declared_metrics(amp, name):
    """Every built-in task, as the task env wires it (motions for the tasks that take them, the
    simulator with the task's ``sim_overrides`` attached), passes ``check_task`` including the rule
    that every metric key it reports is declared with a display name."""
    import inspect

    from mocap.motion.library import MotionLibrary

    bundled_library = MotionLibrary(get_plugins().get("motion_source", "deepmimic").build(None).load(amp), amp)
    component = get_plugins().get("task", name)
    extra = {"motions": bundled_library} if "motions" in inspect.signature(component.resolved_factory()).parameters else {}
    task = component.build(None, skeleton=amp, num_envs=4, device="cpu", **extra)
    task.attach_motions(bundled_library)
    sim = None
    if task.sim_overrides:
        sim_c = get_plugins().get("simulator", "mujoco")
        params = sim_c.validate_params(dict(task.sim_overrides))
        sim = sim_c.build(params, skeleton=amp, num_envs=4, seed=0)
        task.attach(sim)
    try:
        assert "declared metrics" in check_task(task, amp, num_envs=4, declared=component.metrics, sim=sim)
    finally:
        if sim is not None:
            sim.close()


def test_a_task_reporting_an_undeclared_metric_is_caught(amp):
    component = get_plugins().get("task", "speed")
    task = component.build(None, skeleton=amp, num_envs=4, seed=0)
    real = task.metrics
    task.metrics = lambda: {**real(), "mystery": 1.0}  # type: ignore[method-assign]
    with pytest.raises(ContractViolation, match="undeclared key\\(s\\) mystery"):
        check_task(task, amp, num_envs=4, declared=component.metrics)


def _obs(n: int, p: int, g: int) -> Observations:
    gen = torch.Generator().manual_seed(0)
    return Observations(proprio=torch.randn(n, p, generator=gen), goal=torch.randn(n, g, generator=gen))


def test_builtin_latent_spaces_keep_the_contract():
    from mocap_hybrid_rvq.hybrid_params import HybridParams
    from mocap_hybrid_rvq.model import HybridLatent
    from mocap_pulse.latent import PulseLatent
    from mocap_pulse.pulse_params import PulseParams

    P, G, A = 7, 5, 4
    small = {"encoder_hidden": [8], "prior_hidden": [8], "decoder_hidden": [8], "proprio_dim": P, "goal_dim": G, "action_dim": A}
    pulse = PulseLatent(PulseParams(latent_dim=3, **small), P, G, A)
    assert "random_action" in check_latent_space(pulse, _obs(6, P, G), A)
    hybrid = HybridLatent(HybridParams.model_validate({"latent_dim": 4, "num_codebooks": 2, "codebook_size": 6, "single_codebook_size": 12, **small}), P, G, A)
    assert "task action space MultiDiscrete" in check_latent_space(hybrid, _obs(6, P, G), A)


def test_a_broken_task_is_named(amp):
    """The checks fail with the broken promise named, not later in a training run."""
    task = get_plugins().get("task", "speed").build(None, skeleton=amp, num_envs=4, seed=0)
    real = task.observe
    task.observe = lambda state: real(state)[:, :-1]  # type: ignore[method-assign]
    with pytest.raises(ContractViolation, match=r"Task.observe \(step 0\): expected shape \(4, 3\), got \(4, 2\)"):
        check_task(task, amp, num_envs=4)


@pytest.mark.parametrize("name", ["pulse_amp_v2", "hybrid_rvq_amp", "vmp_amp_v2"])
def test_committed_latent_spaces_load_through_their_factory_and_keep_the_contract(amp, name):
    """Every latent-space plugin, as the framework builds it: its registered factory with the
    committed checkpoint (the spec's params), then ``check_latent_space`` on observations built
    the framework's way (VMP's encoder also reads a motion window of the bundled clips)."""
    from pathlib import Path

    import yaml

    from mocap.motion.library import MotionLibrary
    from mocap.observations import proprioception_and_goal

    folder = Path(__file__).resolve().parents[1] / "checkpoints" / name
    spec = yaml.safe_load((folder / "spec.yaml").read_text())
    component = get_plugins().get("latent", spec["latent"]["name"])
    latent = component.build(component.validate_params(spec["latent"].get("params")), skeleton=amp, checkpoint=folder / "latent.pt", device=torch.device("cpu"))
    proprio, goal = proprioception_and_goal(fake_sim_state(amp, 6), fake_sim_state(amp, 6, seed=1))
    extra = {}
    if spec["latent"]["name"] == "vmp":
        lib = MotionLibrary(get_plugins().get("motion_source", "deepmimic").build(None).load(amp), amp)
        extra = {"window": latent.windows(lib, torch.arange(6) * 7 + 20)}
    obs = Observations(proprio=proprio.float(), goal=goal.float(), extra=extra)
    report = check_latent_space(latent, obs, amp.num_dofs)
    assert report[0] == "encoder, prior, decode_action" and "task state round-trip" in report


def test_scratch_keeps_the_contract_without_an_encoder(amp):
    from mocap.observations import proprioception_and_goal

    scratch = get_plugins().get("latent", "scratch").build(None, skeleton=amp, checkpoint=None, device=torch.device("cpu"))
    proprio, goal = proprioception_and_goal(fake_sim_state(amp, 6), fake_sim_state(amp, 6, seed=1))
    report = check_latent_space(scratch, Observations(proprio=proprio.float(), goal=goal.float(), extra={}), amp.num_dofs)
    assert report[0] == "prior, decode_action (no encoder)"
    from mocap.latent_imitator import LatentImitator

    with pytest.raises(ValueError, match="has no encoder"):
        LatentImitator(None, scratch)  # type: ignore[arg-type]
