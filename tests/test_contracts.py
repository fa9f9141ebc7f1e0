"""The roles' contracts are explicit: every optional capability the framework calls is declared on
the interface with a default meaning "not offered", and the framework checks what it cannot declare
(a latent factory must load the checkpoint it is handed)."""

from __future__ import annotations

import ast
from pathlib import Path

import pytest
import torch

from mocap.interfaces import LatentSpace, Simulator, Task
from mocap.state import SimState

ROOT = Path(__file__).resolve().parents[1]


class MinimalTask(Task):
    goal_dim = 1

    def reset(self, env_ids, state):
        pass

    def observe(self, state):
        return torch.zeros(state.num_envs, 1)

    def reward(self, state, actions):
        return torch.zeros(state.num_envs)

    def terminated(self, state):
        return torch.zeros(state.num_envs, dtype=torch.bool)


class MinimalSim(Simulator):
    dt = 1.0 / 30.0  # type: ignore[assignment]

    def __init__(self):
        self.num_envs = 2

    @property
    def state(self) -> SimState:  # pragma: no cover - not called
        raise NotImplementedError

    def reset(self, env_ids, state):  # pragma: no cover - not called
        pass

    def step(self, actions):  # pragma: no cover - not called
        raise NotImplementedError


def test_a_minimal_task_and_simulator_offer_nothing_optional():
    task, sim = MinimalTask(), MinimalSim()
    assert (task.episode_steps, task.max_reward, task.prior_rollout, task.tracks_reference) == (300, 1.0, False, False)
    assert dict(task.sim_overrides) == {} and task.state_dict() == {} and task.markers(0) is None
    frames = object()
    assert task.start_state(torch.arange(2), frames) is frames  # type: ignore[arg-type]
    assert task.truncated(None) is None  # type: ignore[arg-type]
    assert sim.ground_contact is None and sim.get_physics_state() is None and sim.make_recorder(ghost=True) is None
    xy = torch.randn(5, 2, dtype=torch.float64)
    assert torch.equal(sim.height_at(xy), torch.zeros(5, dtype=torch.float64))
    with pytest.raises(NotImplementedError):
        sim.set_physics_state(torch.arange(2), None)  # type: ignore[arg-type]


def test_latent_space_defaults_and_the_scratch_baseline(amp):
    from mocap.hierarchy import ScratchParams
    from mocap.task_env import ScratchLatent

    latent = ScratchLatent(ScratchParams(), amp)
    assert isinstance(latent, LatentSpace) and not latent.samples_prior and not latent.decodes_pd_targets
    assert latent.task_state_dict() == {} and latent.rl_hook() is None and latent.as_imitator(None) is None
    with pytest.raises(NotImplementedError, match="no prior"):
        latent.random_action(None)  # type: ignore[arg-type]


def test_a_latent_factory_that_ignores_its_checkpoint_is_refused(amp):
    from mocap.distill_files import check_latent_loaded
    from mocap.plugins import PluginError
    from mocap_pulse.latent import PulseParams, make_pulse

    ckpt = ROOT / "checkpoints" / "pulse_amp" / "latent.pt"
    params = PulseParams(latent_dim=32, goal_obs="rot", normalizer="teacher")
    check_latent_loaded(make_pulse(params, skeleton=amp, checkpoint=ckpt), ckpt, "pulse")  # loads it: fine
    with pytest.raises(PluginError, match="factory was given the checkpoint .* but returned other weights"):
        check_latent_loaded(make_pulse(params, skeleton=amp), ckpt, "pulse")  # random weights


CAPABILITIES = {  # names of optional capabilities that must be called, never probed with getattr/hasattr
    "random_action",
    "decode_action",
    "reset_envs",
    "task_state_dict",
    "load_task_state_dict",
    "decodes_pd_targets",
    "attach_imitator",
    "as_imitator",
    "init_from_teacher",
    "update_normalizers",
    "rl_hook",
    "student_action",
    "episode_steps",
    "max_reward",
    "prior_rollout",
    "prior_noise_scale",
    "sim_overrides",
    "attach",
    "attach_motions",
    "start_state",
    "reference_start",
    "step",
    "truncated",
    "state_dict",
    "load_state_dict",
    "markers",
    "get_physics_state",
    "set_physics_state",
    "make_recorder",
    "ground_contact",
    "height_at",
    "make_env",
    "after_iteration",
    "policy",
    "observation",
    "data_parallel",
    # the simulator capabilities tasks and trainers use (mocap.interfaces.MovableTarget, ExternalWrench, PerEnvModels)
    "has_target",
    "set_target",
    "target_state",
    "set_external_wrench",
    "env_models",
}


def test_the_framework_never_probes_for_a_declared_capability():
    found = []
    for path in sorted((ROOT / "core").rglob("*.py")) + sorted((ROOT / "plugins").rglob("*.py")):
        for node in ast.walk(ast.parse(path.read_text())):
            if isinstance(node, ast.Call) and isinstance(node.func, ast.Name) and node.func.id in ("getattr", "hasattr"):
                if len(node.args) >= 2 and isinstance(node.args[1], ast.Constant) and node.args[1].value in CAPABILITIES:
                    found.append(f"{path.relative_to(ROOT)}:{node.lineno} {node.func.id}(..., {node.args[1].value!r})")
                elif len(node.args) >= 2 and not isinstance(node.args[1], ast.Constant) and (node.func.id == "hasattr" or len(node.args) == 3):
                    # a probe through a variable name (hasattr(sim, need), getattr(x, name, None)): the name is unknown here
                    found.append(f"{path.relative_to(ROOT)}:{node.lineno} {ast.unparse(node)}")
    assert not found, "declare these on the interface instead of probing:\n" + "\n".join(found)
