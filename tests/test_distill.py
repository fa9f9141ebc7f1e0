"""The ``distill`` trainer (online DAgger-style distillation into a DistillableLatent) and
:class:`mocap.latent_imitator.LatentImitator`, with a tiny PHC teacher and a tiny PULSE student on
the bundled walk clip."""

from __future__ import annotations

import io
import json
import types
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import pytest
import torch
from hypothesis import given, settings
from hypothesis import strategies as st
from rich.console import Console

torch.set_num_threads(1)


import mocap.distill  # noqa: E402
import mocap_pulse.plugin  # noqa: E402
from mocap.baselines import PDReplay  # noqa: E402
from mocap.checkpoint import load_checkpoint  # noqa: E402
from mocap.distill import DistillParams, mixture_beta  # noqa: E402
from mocap.distill_files import load_latent_state  # noqa: E402
from mocap.distill_trainer import DistillTrainer  # noqa: E402
from mocap.hard_negatives import failure_weights  # noqa: E402
from mocap.imitation_eval import rollout_imitation  # noqa: E402
from mocap.interfaces import Box, StageResult  # noqa: E402
from mocap.latent_imitator import LatentImitator  # noqa: E402
from mocap.motion.deepmimic import DeepMimicParams, DeepMimicSource  # noqa: E402
from mocap.motion.library import MotionLibrary  # noqa: E402
from mocap.runlog import MetricsLogger  # noqa: E402
from mocap_phc.imitator import PHCParams, make_phc  # noqa: E402
from mocap_pulse.latent import PulseLatent, PulseParams, make_pulse  # noqa: E402

STUDENT = dict(latent_dim=16, encoder_hidden=[64], prior_hidden=[32], decoder_hidden=[64, 64])


def make_sim(skeleton, n):
    from mocap_sim_mujoco.simulator import MujocoSimulator

    return MujocoSimulator(skeleton=skeleton, num_envs=n, seed=0, dtype=torch.float32)


@pytest.fixture(scope="module")
def walk(amp):
    return DeepMimicSource(DeepMimicParams(clips=["walk"])).load(amp)


@pytest.fixture(scope="module")
def teacher_file(amp, walk, tmp_path_factory):
    """A small random PHC policy (residual actions of about 0.1 rad), its input normalizer fitted to
    reference states of the walk as a trained policy's would be, saved as a policy file."""
    from mocap.rl.networks import ActorCritic, save_policy
    from mocap_phc.env import PHCObservation

    torch.manual_seed(0)
    obs_dim = 15 * amp.num_bodies - 2 + 24 * amp.num_bodies
    model = ActorCritic(obs_dim, Box((amp.num_dofs,)), actor_hidden=(32,), critic_hidden=(8,))
    lib = MotionLibrary(walk, amp)
    ids, times = lib.sample(64, generator=torch.Generator().manual_seed(0))
    model.obs_norm.update(PHCObservation.flatten(PHCObservation()(lib.frames(ids, times), lib.frames(ids, times + 1 / 30))))
    with torch.no_grad():
        model.action_head.weight.mul_(5.0)
    path = tmp_path_factory.mktemp("teacher") / "policy.pt"
    save_policy(path, model)
    return path


@dataclass
class FakeContext:
    """The part of :class:`mocap.pipeline.StageContext` the distill trainer uses."""

    workdir: Path
    skeleton: Any
    motions: Any
    teacher_file: Path
    student: dict[str, Any] = field(default_factory=lambda: dict(STUDENT))
    seed: int = 0
    stop_after: int | None = None
    device: torch.device = torch.device("cpu")
    console: Console = field(default_factory=lambda: Console(file=io.StringIO()))
    calls: int = 0

    def __post_init__(self) -> None:
        self.log = MetricsLogger(self.workdir / "metrics.jsonl", "latent")
        self.upstream = {"imitator": StageResult(checkpoint=self.teacher_file)}

    def stage_component(self, stage: str | None = None, checkpoint: Path | None = None) -> Any:
        if stage == "imitator":
            return make_phc(PHCParams(action="residual"), skeleton=self.skeleton, checkpoint=checkpoint)
        return make_pulse(PulseParams(**self.student), skeleton=self.skeleton, checkpoint=checkpoint)

    def build(self, path: str, **kwargs: Any) -> Any:
        if path == "motions":
            return types.SimpleNamespace(load=lambda skeleton: self.motions)
        assert path == "simulator"
        return make_sim(kwargs["skeleton"], kwargs["num_envs"])

    def should_stop(self) -> bool:
        self.calls += 1
        return self.stop_after is not None and self.calls >= self.stop_after

    def spec_yaml(self) -> str:
        return "name: fake\n"


def run(ctx: FakeContext, params: DistillParams) -> StageResult:
    try:
        return DistillTrainer(params).run(ctx)
    finally:
        ctx.log.close()


def records(path: Path) -> list[dict[str, Any]]:
    return [json.loads(line) for line in (path / "metrics.jsonl").read_text().splitlines()]


# ------------------------------------------------------------------------------------ helpers
@settings(max_examples=40, deadline=None)
@given(counts=st.lists(st.one_of(st.just(0.0), st.floats(1e-3, 10)), min_size=1, max_size=6), floor=st.floats(0, 1))
def test_failure_weights(counts, floor):
    f = torch.tensor(counts, dtype=torch.float64)
    base = torch.ones_like(f)
    w = failure_weights(f, base, floor)
    assert float(w.sum()) == pytest.approx(1.0) and bool((w >= 0).all())
    if float(f.sum()) == 0:
        assert torch.allclose(w, base / base.sum())
    elif floor == 0:
        assert torch.equal(w > 0, f > 0)
    else:
        assert bool((w >= floor / len(counts) - 1e-12).all())


def test_mixture_beta_and_params():
    assert mixture_beta(0.0, 1.0, 0.0, 0.5) == 1.0 and mixture_beta(0.25, 1.0, 0.0, 0.5) == 0.5
    assert mixture_beta(0.7, 1.0, 0.0, 0.5) == 0.0
    with pytest.raises(ValueError, match="minibatch_envs"):
        DistillParams(num_envs=4, minibatch_envs=8)
    with pytest.raises(ValueError, match="mixture_beta"):
        DistillParams(mixture_beta=(1.5, 0.0))
    for name, f in DistillParams.model_fields.items():
        assert f.description, name
    from mocap.testing import use_plugins

    with use_plugins(("distill", mocap.distill)) as pset:
        trainer = pset.get("trainer", "distill").build({"num_envs": 8, "minibatch_envs": 4})
    assert isinstance(trainer, DistillTrainer) and trainer.params.num_envs == 8


# ---------------------------------------------------------------------------------- training
def test_distillation_lowers_the_action_loss(amp, walk, teacher_file, tmp_path):
    params = DistillParams(num_envs=6, horizon=16, total_env_steps=6 * 16 * 12, epochs=8, minibatch_envs=3, lr=2e-3, eval_every=6, eval_horizon=0.5)
    ctx = FakeContext(tmp_path, amp, walk, teacher_file)
    result = run(ctx, params)
    recs = records(tmp_path)
    loss = [r["loss/action"] for r in recs]
    assert len(loss) == 12 and all(r["step"] == i + 1 for i, r in enumerate(recs))
    first, last = sum(loss[:2]) / 2, sum(loss[-2:]) / 2
    assert last < 0.6 * first and max(loss[-4:]) < min(loss[:2]), loss
    assert recs[-1]["episode/length"] > 0 and recs[-1]["rollout/action_gap"] > 0  # episodes ended and were reset
    assert "eval/success_rate" in recs[5] and "eval/mpjpe_g" in recs[-1] and "eval/success_rate" not in recs[4]
    assert recs[-1]["loss/beta"] == pytest.approx(0.001)  # progress 11/12 is past the default anneal window
    assert result.checkpoint == tmp_path / "latent.pt" and result.metrics["iterations"] == 12
    # the latent factory rebuilds the trained student from latent.pt (and from distill.pt)
    trained = make_pulse(PulseParams(**STUDENT), skeleton=amp, checkpoint=result.checkpoint)
    mid = make_pulse(PulseParams(**STUDENT), skeleton=amp, checkpoint=tmp_path / "distill.pt")
    assert all(torch.equal(a, b) for a, b in zip(trained.parameters(), mid.parameters()))
    assert load_latent_state(result.checkpoint)["spec"] == "name: fake\n"
    assert float(trained.proprio_norm.count) == 6 * 16 * 12


def test_resume_is_exact(amp, walk, teacher_file, tmp_path):
    params = DistillParams(
        num_envs=4,
        horizon=8,
        total_env_steps=4 * 8 * 4,
        epochs=2,
        minibatch_envs=2,
        checkpoint_every=3,
        eval_every=1,
        eval_horizon=0.3,
        update_every=2,
        act_with="mixture",
        mixture_beta=(0.8, 0.2),
        mixture_anneal_end=1.0,
    )
    run(FakeContext(tmp_path / "straight", amp, walk, teacher_file), params)
    straight = load_checkpoint(tmp_path / "straight" / "distill.pt")

    split = tmp_path / "split"
    stopped = run(FakeContext(split, amp, walk, teacher_file, stop_after=2), params)  # Ctrl-C after iteration 2
    assert stopped.checkpoint == split / "distill.pt" and not (split / "latent.pt").exists()
    assert load_checkpoint(split / "distill.pt")["iteration"] == 2
    with (split / "metrics.jsonl").open("a") as fh:  # a line logged after the checkpoint, before a crash
        fh.write(json.dumps({"stage": "latent", "step": 3}) + "\n")
    run(FakeContext(split, amp, walk, teacher_file), params)
    resumed = load_checkpoint(split / "distill.pt")

    assert resumed["iteration"] == straight["iteration"] == 4 and resumed["finished"]
    for key, value in straight["student"].items():
        if isinstance(value, torch.Tensor):
            assert torch.equal(value, resumed["student"][key]), key
    for sid, s in straight["optimizer"]["state"].items():
        for k, v in s.items():
            assert torch.equal(v, resumed["optimizer"]["state"][sid][k]), (sid, k)
    assert torch.equal(straight["episodes"]["physics"], resumed["episodes"]["physics"])
    assert torch.equal(straight["episodes"]["fail_counts"], resumed["episodes"]["fail_counts"])
    assert float(straight["episodes"]["fail_counts"].sum()) > 0  # evaluation-driven mining happened
    assert [r["step"] for r in records(split)] == [1, 2, 3, 4]
    a, b = records(tmp_path / "straight")[-1], records(split)[-1]
    assert a["loss/total"] == b["loss/total"] and a["rollout/teacher_fraction"] == b["rollout/teacher_fraction"]


def test_dimension_mismatch_is_reported(amp, walk, teacher_file, tmp_path):
    ctx = FakeContext(tmp_path, amp, walk, teacher_file, student={**STUDENT, "goal_obs": "keypoint"})
    from mocap.errors import StageFailed

    with pytest.raises(StageFailed, match="goal"):  # a stage error: one line from the CLI, not a traceback
        run(ctx, DistillParams(num_envs=2, horizon=2, total_env_steps=4, minibatch_envs=2, eval_every=0))


# ----------------------------------------------------------------------------- LatentImitator
def test_latent_imitator_runs_through_rollout_imitation(amp, walk, teacher_file):
    """With the decoder's last layer zeroed the student outputs a zero residual, so the latent
    imitator is PD replay (PD targets = next reference pose) through the teacher's mapping."""
    lib = MotionLibrary(walk, amp)
    teacher = make_phc(PHCParams(action="residual"), skeleton=amp, checkpoint=teacher_file)
    latent = make_pulse(PulseParams(**STUDENT), skeleton=amp)
    ids, frames = torch.tensor([0]), torch.tensor([12])
    out = rollout_imitation(make_sim(amp, 1), lib, LatentImitator(teacher, latent), ids, frames, threshold=10.0)
    assert out.traj.sim.shape == (13, 1, amp.num_bodies, 3) and bool(torch.isfinite(out.traj.sim).all())
    last = latent.dec[-1]
    assert isinstance(last, torch.nn.Linear)
    with torch.no_grad():
        last.weight.zero_()
        last.bias.zero_()
    imitator = LatentImitator(teacher, latent)
    assert isinstance(latent, PulseLatent) and latent._pd_map is not None  # attached: latent.decoder gives PD targets
    out_a = rollout_imitation(make_sim(amp, 1), lib, imitator, ids, frames, threshold=10.0)
    out_b = rollout_imitation(make_sim(amp, 1), lib, PDReplay(), ids, frames, threshold=10.0)
    assert torch.equal(out_a.traj.sim, out_b.traj.sim)


# --------------------------------------------------------------------------------- as a stage
def _tiny_pulse_spec(name: str, teacher: Path) -> str:
    """A spec distilling a 4-dim PULSE from ``teacher`` on the walk clip in a few steps."""
    return f"""\
spec_version: 1
name: {name}
device: cpu
humanoid: {{name: amp}}
motions: {{name: deepmimic, params: {{clips: [walk]}}}}
simulator: {{name: mujoco}}
imitator: {{name: phc, params: {{action: residual}}, checkpoint: {teacher}}}
latent:
  name: pulse
  params: {{latent_dim: 4, encoder_hidden: [16], prior_hidden: [16], decoder_hidden: [16]}}
  trainer: {{name: distill, params: {{num_envs: 2, horizon: 4, total_env_steps: 16, minibatch_envs: 2, eval_every: 2, eval_horizon: 0.2, act_with: teacher}}}}
"""


def test_distill_runs_as_a_pipeline_stage(amp, teacher_file, tmp_path):
    """The real wiring: spec validation, ``ctx.stage_component``, ``ctx.build``, DONE.json, and the
    latent factory rebuilding the trained student from the stage's checkpoint."""
    from mocap.pipeline import run_pipeline
    from mocap.spec import load_spec_text
    from mocap.testing import use_plugins

    spec = _tiny_pulse_spec("pulse_tiny", teacher_file)
    with use_plugins(("distill", mocap.distill), ("latent_pulse", mocap_pulse.plugin)) as pset:
        resolved = load_spec_text(spec, pset)
        records_ = run_pipeline(resolved, pset, tmp_path / "run", console=Console(file=io.StringIO()))
        latent_record = records_[-1]
        assert latent_record.stage == "latent" and latent_record.result.checkpoint == latent_record.workdir / "latent.pt"
        assert (latent_record.workdir / "DONE.json").is_file() and "eval/success_rate" in latent_record.result.metrics
        latent = pset.get("latent", "pulse").build(resolved.params["latent"], skeleton=amp, checkpoint=latent_record.result.checkpoint, device="cpu")
    assert isinstance(latent, PulseLatent) and latent.latent_dim == 4
    steps = [json.loads(line)["step"] for line in (tmp_path / "run" / "metrics.jsonl").read_text().splitlines()]
    assert steps == [1, 2]


def test_pd_target_labels_make_the_student_independent_of_the_reference(amp, walk, teacher_file, tmp_path):
    """``label: pd_targets``: the student learns the teacher's PD targets and steps the simulator
    with its own output, no reference-dependent mapping (what tasks need from a residual teacher)."""
    from mocap.latent_imitator import PDTargetTeacher

    ctx = FakeContext(tmp_path, amp, walk, teacher_file)
    teacher = ctx.stage_component("imitator", checkpoint=teacher_file)
    wrapped = PDTargetTeacher(teacher)
    from mocap.motion.library import MotionLibrary
    from mocap.plugins import get_plugins

    lib = MotionLibrary(walk, amp)
    sim = get_plugins().get("simulator", "mujoco").build({}, skeleton=amp, num_envs=2, seed=0)
    sim.reset(torch.arange(2), lib.frames(torch.zeros(2, dtype=torch.long), torch.zeros(2)))
    obs = wrapped.observe(sim.state, lib.frames(torch.zeros(2, dtype=torch.long), torch.full((2,), 1 / 30)))
    out = wrapped.policy_output(obs)
    assert torch.equal(out, teacher.act(obs)) and torch.equal(wrapped.to_pd_targets(obs, out), out)
    assert not torch.allclose(out, teacher.policy_output(obs))  # residual teacher: raw output != PD targets
    sim.close()
    params = DistillParams(num_envs=4, horizon=8, total_env_steps=4 * 8 * 3, epochs=2, minibatch_envs=2, label="pd_targets", eval_every=0)
    result = run(ctx, params)
    assert load_latent_state(result.checkpoint)["extra"]["label"] == "pd_targets"
    assert all(r["loss/action"] >= 0 for r in records(tmp_path))


def test_distill_without_an_imitator_is_a_clear_error(tmp_path):
    from mocap.testing import invoke

    spec = tmp_path / "s.yaml"
    spec.write_text("spec_version: 1\nname: no-teacher\nmotions: {name: deepmimic, params: {clips: [walk]}}\nlatent: {name: pulse, trainer: {name: distill}}\n")
    result = invoke(["run", spec, "--out", tmp_path / "runs" / "x"])
    assert result.exit_code == 2 and "Traceback" not in result.output
    assert "needs a teacher" in result.stderr


def test_fallen_starts_and_bonus_recovery_episodes_in_distillation(amp, walk):
    """PULSE's code distills with fallen-state starts and recovery episodes (issue 27 item 6): a
    fallen start lies low, gets a recovery window in which tracking failures do not end it, and
    a failure outside the window may go on as a bonus recovery episode."""
    from mocap.distill_episodes import DistillEpisodes
    from mocap.fail_states import FailStateParams

    lib = MotionLibrary(walk, amp)
    fs = FailStateParams(fall_init_prob=1.0, recovery_steps=6, settle_steps=30, pool_size=4)
    ep = DistillEpisodes(DistillParams(num_envs=4, minibatch_envs=4, fail_states=fs), lib, make_sim(amp, 4), seed=0)
    ep.reset_all()
    assert bool((ep.recovery_left == 6).all())
    assert float(ep.sim.state.root_pos[:, 2].max()) < 0.5  # lying on the ground, not standing at the reference
    zeros = ep.sim.state.dof_pos.clone()
    for k in range(5):  # far from the reference, but inside the window: no termination
        state = ep.sim.step(zeros)
        out = ep.after_step(state, ep.reference_next())
        assert not bool(out["terminated"].any()), k
    # bonus episodes: every failure after the window goes on with a fresh window
    ep2 = DistillEpisodes(
        DistillParams(num_envs=4, minibatch_envs=4, fail_states=FailStateParams(recovery_episode_prob=1.0, recovery_steps=3)),
        lib,
        make_sim(amp, 4),
        seed=0,
    )
    ep2.reset_all()
    far = ep2.reference_next()
    far.body_pos += 5.0  # a reference 5 m away: every env fails the 0.5 m criterion
    out = ep2.after_step(ep2.sim.step(ep2.sim.state.dof_pos.clone()), far)
    assert not bool(out["terminated"].any()) and bool((ep2.recovery_left == 3).all())
    # off (the default): the same failure terminates
    ep3 = DistillEpisodes(DistillParams(num_envs=4, minibatch_envs=4), lib, make_sim(amp, 4), seed=0)
    ep3.reset_all()
    far = ep3.reference_next()
    far.body_pos += 5.0
    assert bool(ep3.after_step(ep3.sim.step(ep3.sim.state.dof_pos.clone()), far)["terminated"].all())


def test_distillation_episodes_are_built_on_the_episode_layer(amp):
    """Starts come from mocap.episodes.ReferenceStarts (same draws for the same generator), a
    non-looping clip's end truncates, and termination is the terms ``tracking`` OR ``unstable``: an
    unstable env terminates even where it tracks the reference."""
    from dataclasses import replace

    from mocap.distill_episodes import DistillEpisodes
    from mocap.episodes import ReferenceStarts, TerminationTerms

    lib = MotionLibrary(DeepMimicSource(DeepMimicParams(clips=["walk", "punch"])).load(amp), amp)
    ep = DistillEpisodes(DistillParams(num_envs=6, minibatch_envs=6, episode_steps=1000), lib, make_sim(amp, 6), seed=0)
    assert isinstance(ep.starts, ReferenceStarts) and isinstance(ep.termination, TerminationTerms)
    assert ep.termination.enabled == {"tracking": True, "unstable": True}
    ep.reset_all()
    clips, t0 = ReferenceStarts(lib, ep.dt, control_grid=True).sample(6, torch.Generator().manual_seed(0))
    assert torch.equal(ep.clip_ids, clips) and torch.equal(ep.start_time, t0)
    ref = ep.reference_next()
    state = ep.sim.step(ref.dof_pos.float())
    state = replace(state, body_pos=ref.body_pos.to(state.body_pos), unstable=torch.tensor([True] + [False] * 5))
    out = ep.after_step(state, ref)
    assert out["terminated"].tolist() == [True] + [False] * 5 and not bool(out["truncated"][0])
    # a non-looping clip: the step that reaches past its end truncates (the looping walk goes on)
    punch = lib.clip_names.index("punch")
    ep.clip_ids[:] = punch
    ep.start_time[:] = float(lib.durations[punch]) - 1.5 * ep.dt
    ep.progress[:] = 0
    ref = ep.reference_next()
    state = replace(ep.sim.step(ref.dof_pos.float()), body_pos=ref.body_pos.float())
    out = ep.after_step(state, ref)
    assert bool(out["truncated"].all()) and not bool(out["terminated"].any()) and out["length"].tolist() == [1] * 6


def test_teacher_of_another_humanoid_variant_is_refused(amp, teacher_file, tmp_path):
    """A teacher trained on the amp humanoid with other params (its embedded spec says so) is not
    distilled onto the default amp humanoid: the stage fails naming the difference (a clamped
    teacher would otherwise be distilled without any error)."""
    from mocap.checkpoint import load_checkpoint, save_checkpoint
    from mocap.pipeline import run_pipeline
    from mocap.spec import load_spec_text
    from mocap.testing import use_plugins

    data = load_checkpoint(teacher_file)
    variant = tmp_path / "teacher_free.pt"
    save_checkpoint(variant, data, spec_yaml="humanoid:\n  name: amp\n  params: {shoulder_turns: 8.0}\n")
    spec = _tiny_pulse_spec("pulse_variant", variant)
    with use_plugins(("distill", mocap.distill), ("latent_pulse", mocap_pulse.plugin)) as pset:
        resolved = load_spec_text(spec, pset)
        with pytest.raises(Exception, match=r"shoulder_turns: 8\.0.*right_shoulder_y\.range"):
            run_pipeline(resolved, pset, tmp_path / "run", console=Console(file=io.StringIO()))
