"""The built-in components pass the conformance checks plugin authors use (mocap.testing)."""

from __future__ import annotations

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


@pytest.mark.parametrize("name", ["speed", "reach", "point_goal", "terrain"])
def test_builtin_tasks_keep_the_contract(amp, name):
    task = get_plugins().get("task", name).build(None, skeleton=amp, num_envs=4, seed=0)
    assert "state_dict round-trip" in check_task(task, amp, num_envs=4)


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
    hybrid = HybridLatent(
        HybridParams.model_validate({"latent_dim": 4, "num_codebooks": 2, "codebook_size": 6, "single_codebook_size": 12, **small}), P, G, A
    )
    assert "task action space MultiDiscrete" in check_latent_space(hybrid, _obs(6, P, G), A)


def test_a_broken_task_is_named(amp):
    """The checks fail with the broken promise named, not later in a training run."""
    task = get_plugins().get("task", "speed").build(None, skeleton=amp, num_envs=4, seed=0)
    real = task.observe
    task.observe = lambda state: real(state)[:, :-1]  # type: ignore[method-assign]
    with pytest.raises(ContractViolation, match=r"Task.observe \(step 0\): expected shape \(4, 3\), got \(4, 2\)"):
        check_task(task, amp, num_envs=4)
