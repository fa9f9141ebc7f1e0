"""Tests of PMCP (``mocap_phc.pmcp``): the composer formulas, the hard-set and plateau rules, and the
``pmcp`` trainer end to end through the pipeline (phases, ``pmcp.pt`` with ``make_phc`` and
``mocap eval``, bit-exact resume after Ctrl-C in every phase)."""

from __future__ import annotations

import io
import json
from pathlib import Path

import pytest
import torch
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st
from pydantic import ValidationError

torch.set_num_threads(1)

import mocap_phc.plugin  # noqa: F401  (registers phc and pmcp)
from mocap.checkpoint import load_checkpoint
from mocap.interfaces import Box
from mocap.rl.networks import ActorCritic
from mocap_phc.pmcp import (
    CompositeImitator,
    CompositePolicy,
    PlateauTracker,
    PMCPParams,
    compose,
    composer_bias,
    next_hard_set,
    unique_clip_names,
)

SETTINGS = settings(max_examples=40, deadline=None, suppress_health_check=[HealthCheck.too_slow, HealthCheck.function_scoped_fixture])
F64 = torch.float64


# ---------------------------------------------------------------------------- composer math
def _means(seed: int, n: int, k: int, a: int) -> torch.Tensor:
    g = torch.Generator().manual_seed(seed)
    return torch.randn(n, k, a, generator=g, dtype=F64)


dims = st.tuples(st.integers(1, 4), st.integers(1, 5), st.integers(1, 6))  # N, K, A
seeds = st.integers(0, 2**31 - 1)


@SETTINGS
@given(dims, seeds, st.floats(1e-3, 10.0), st.sampled_from([0.0, 1e-6]))
def test_multiplicative_equal_weights_give_the_mean_of_the_means(d, seed, w, eps):
    n, k, a = d
    mu = _means(seed, n, k, a)
    out = compose(torch.full((n, k), w, dtype=F64), mu, "multiplicative", eps)
    torch.testing.assert_close(out, mu.mean(-2))


@SETTINGS
@given(dims, seeds, st.data(), st.floats(1e-2, 5.0))
def test_one_hot_weights_select_one_primitive(d, seed, data, scale):
    n, k, a = d
    mu = _means(seed, n, k, a)
    j = data.draw(st.integers(0, k - 1))
    w = torch.zeros(n, k, dtype=F64)
    w[:, j] = 1.0
    torch.testing.assert_close(compose(w, mu, "weighted_sum"), mu[:, j])
    torch.testing.assert_close(compose(scale * w, mu, "multiplicative", 0.0), mu[:, j])
    # the default eps only nudges the selection by O(eps)
    bound = k * 1e-6 / scale * 2 * float(mu.abs().max()) + 1e-12  # |a - mu_j| <= (K-1) eps / scale * max|mu_i - mu_j|
    torch.testing.assert_close(compose(scale * w, mu, "multiplicative", 1e-6), mu[:, j], atol=bound, rtol=0)
    # negative weights on the others are clamped away by the ReLU
    w2 = w - 3.0 * (1.0 - w)
    torch.testing.assert_close(compose(w2, mu, "weighted_sum"), mu[:, j])
    torch.testing.assert_close(compose(scale * w2, mu, "multiplicative", 0.0), mu[:, j])


@SETTINGS
@given(dims, seeds, st.floats(0.0, 3.0), st.floats(0.0, 3.0))
def test_weighted_sum_is_linear_in_nonnegative_weights(d, seed, alpha, beta):
    n, k, a = d
    mu = _means(seed, n, k, a)
    g = torch.Generator().manual_seed(seed + 1)
    w1, w2 = torch.rand(n, k, generator=g, dtype=F64), torch.rand(n, k, generator=g, dtype=F64)
    lhs = compose(alpha * w1 + beta * w2, mu, "weighted_sum")
    rhs = alpha * compose(w1, mu, "weighted_sum") + beta * compose(w2, mu, "weighted_sum")
    torch.testing.assert_close(lhs, rhs)
    torch.testing.assert_close(lhs, torch.einsum("nk,nka->na", alpha * w1 + beta * w2, mu))


@SETTINGS
@given(dims, seeds, st.sampled_from(["weighted_sum", "multiplicative"]))
def test_relu_clamps_negative_weights(d, seed, form):
    n, k, a = d
    mu = _means(seed, n, k, a)
    g = torch.Generator().manual_seed(seed + 2)
    w = torch.randn(n, k, generator=g, dtype=F64)
    torch.testing.assert_close(compose(w, mu, form), compose(w.clamp_min(0.0), mu, form))
    neg = -torch.rand(n, k, generator=g, dtype=F64) - 0.1
    assert torch.equal(compose(neg, mu, "weighted_sum"), torch.zeros(n, a, dtype=F64))
    torch.testing.assert_close(compose(neg, mu, "multiplicative", 0.0), mu.mean(-2))  # fallback: the mean
    # multiplicative is a convex combination: inside the per-dimension range of the means
    out = compose(w, mu, "multiplicative")
    assert torch.all(out <= mu.max(-2).values + 1e-9) and torch.all(out >= mu.min(-2).values - 1e-9)


@SETTINGS
@given(dims, seeds, st.data())
def test_composer_bias_per_primitive_starts_the_composite_as_one_primitive(d, seed, data):
    """`composer_init_weight` as one value per primitive: [0, .., 1, .., 0] makes the first composite
    the chosen primitive alone (multiplicative form, up to the eps nudge); None and a number fill."""
    n, k, a = d
    mu = _means(seed, n, k, a)
    j = data.draw(st.integers(0, k - 1))
    bias = composer_bias([1.0 if i == j else 0.0 for i in range(k)], k)
    out = compose(bias.to(F64).expand(n, k), mu, "multiplicative", 0.0)
    torch.testing.assert_close(out, mu[:, j])
    assert torch.equal(composer_bias(None, k), torch.full((k,), 1.0 / k))
    assert torch.equal(composer_bias(0.3, k), torch.full((k,), 0.3))
    with pytest.raises(ValueError, match=f"for {k + 1} primitives"):
        composer_bias([1.0] * k, k + 1)


def test_composer_init_weights_must_fit_the_primitives():
    PMCPParams(max_primitives=1, composer_init_weight=[1.0])
    with pytest.raises(ValidationError, match="at most 1 primitives"):
        PMCPParams(max_primitives=1, composer_init_weight=[1.0, 0.0])
    assert PMCPParams(max_primitives=1, recovery={"clips": ["walk"]}, composer_init_weight=[1.0, 0.0]).composer_init_weight == [1.0, 0.0]


def test_composite_policy_mixes_each_primitive_on_its_own_normalizer():
    torch.manual_seed(0)
    prims = [ActorCritic(5, Box((3,)), [8], [8]) for _ in range(2)]
    prims[0].obs_norm.update(torch.randn(50, 5) * 3 + 1)  # different saved statistics
    prims[1].obs_norm.update(torch.randn(50, 5) * 0.5 - 2)
    composer = ActorCritic(5, Box((2,)), [8], [8])
    obs = torch.randn(7, 5)
    for form in ("weighted_sum", "multiplicative"):
        pol = CompositePolicy(prims, composer, form)
        mu = torch.stack([p.mean_action(obs) for p in prims], -2)
        torch.testing.assert_close(pol.mean_action(obs), compose(composer.mean_action(obs), mu, form))
        assert pol.act(obs)[0].shape == (7, 3)
    with pytest.raises(ValueError, match="weights"):
        CompositePolicy(prims[:1], composer, "weighted_sum")


# ------------------------------------------------------------------------ subset and plateau
@SETTINGS
@given(st.integers(1, 12), st.integers(1, 5), seeds)
def test_hard_sets_are_the_failures_and_nest(num_clips, stages, seed):
    g = torch.Generator().manual_seed(seed)
    hard = list(range(num_clips))
    for _ in range(stages):
        success = (torch.rand(len(hard), generator=g) < 0.5).tolist()
        nxt = next_hard_set(hard, success)
        assert set(nxt) <= set(hard)  # H_{k+1} ⊆ H_k
        assert nxt == [c for c, ok in zip(hard, success) if not ok]  # exactly k's failures, in order
        hard = nxt
    with pytest.raises(ValueError):
        next_hard_set([0, 1], [True])


def test_plateau_rule_on_a_synthetic_sequence():
    T, F = True, False
    tr = PlateauTracker(patience=2, num_clips=3)
    seq = [
        ([F, F, F], True, 0),  # the first evaluation always improves
        ([F, F, F], False, 1),
        ([T, F, F], True, 0),  # more clips than ever
        ([F, T, F], True, 0),  # same count, but clip 1 succeeds for the first time
        ([T, F, F], False, 1),  # nothing new
        ([F, F, F], False, 2),  # worse: still no improvement -> plateau
    ]
    for i, (s, improved, stale) in enumerate(seq):
        assert tr.update(i, s) is improved, i
        assert tr.stale == stale
        assert tr.plateaued is (stale >= 2)
    assert not tr.all_success
    tr.update(6, [T, T, T])  # an improvement resets the count
    assert tr.stale == 0 and not tr.plateaued and tr.all_success
    copy = PlateauTracker(2, 3)
    copy.load_state_dict(json.loads(json.dumps(tr.state_dict())))
    assert copy.state_dict() == tr.state_dict()
    never = PlateauTracker(patience=0, num_clips=1)
    for i in range(10):
        never.update(i, [False])
    assert never.stale == 9 and not never.plateaued  # patience 0: budget only
    with pytest.raises(ValueError):
        tr.update(7, [T])


def test_params_and_names():
    p = PMCPParams()
    assert p.max_primitives == 3 and p.init == "copy" and p.composer_form == "multiplicative"
    assert p.composer_ppo.log_std_init == -2.9 and not p.composer_ppo.learn_std
    with pytest.raises(ValidationError):
        PMCPParams(bogus=1)
    with pytest.raises(ValidationError):
        PMCPParams(composer_form="sum")
    assert unique_clip_names(["a", "b", "a", "a"]) == ["a", "b", "a#2", "a#3"]


# --------------------------------------------------------------------------------- end to end
SPEC = """\
spec_version: 1
name: pmcp_tiny
device: cpu
humanoid: {name: amp}
motions: {name: deepmimic, params: {clips: [walk, kick]}}
simulator: {name: mujoco}
imitator:
  name: phc
  params: {action: residual, episode_steps: 20, eval_every: 0, energy_coef: 0.0}
  trainer:
    name: pmcp
    params:
      ppo: {num_envs: 4, horizon: 16, total_env_steps: 1024, minibatch_size: 32, epochs: 1, actor_hidden: [16], critic_hidden: [16], checkpoint_every: 2}
      primitive_env_steps: 320
      eval_every: 1
      plateau_evals: 2
      max_primitives: 2
      composer_form: weighted_sum
      composer_ppo: {num_envs: 4, horizon: 16, total_env_steps: 192, minibatch_size: 32, epochs: 1, actor_hidden: [16], critic_hidden: [16], \
log_std_init: -2.9, learn_std: false, checkpoint_every: 2}
"""


@pytest.fixture(scope="module")
def straight(tmp_path_factory):
    """One uninterrupted ``mocap run`` of the tiny PMCP spec."""
    from mocap.testing import invoke

    root = tmp_path_factory.mktemp("pmcp")
    spec = root / "spec.yaml"
    spec.write_text(SPEC)
    result = invoke(["run", spec, "--out", root / "runs" / "t"])
    assert result.exit_code == 0, result.output
    stages = json.loads((root / "runs" / "t" / "stages.json").read_text())
    return root, Path(stages[0]["checkpoint"])


def test_pmcp_stage_end_to_end(straight, amp):
    from mocap.testing import invoke

    root, final = straight
    workdir = final.parent
    assert final.name == "pmcp.pt"
    state = json.loads((workdir / "pmcp_state.json").read_text())
    assert state["phase"] == "done" and state["clip_names"] == ["walk", "kick"]
    prims = state["primitives"]
    assert prims[0]["clip_ids"] == [0, 1] and prims[0]["status"] == "frozen"
    # plateau: evaluated every iteration, frozen after 2 evaluations without improvement (or on full success)
    for pr in prims:
        hist = pr["evaluations"]
        assert pr["end"] in ("plateau", "all_success", "budget")
        if pr["end"] == "plateau":
            assert len(hist) >= 3 and not any(h["improved"] for h in hist[-2:])
        assert pr["env_steps"] <= 320 + 64
    # the subset rule: primitive k+1 trained exactly on the clips primitive k failed at its freeze
    failed0 = [i for i in prims[0]["clip_ids"] if not prims[0]["evaluation"]["clips"][state["clip_names"][i]]["success"]]
    if failed0:
        assert len(prims) == 2 and prims[1]["clip_ids"] == failed0
        env_state = load_checkpoint(workdir / "prim1" / "ppo.pt")["env"]
        assert env_state["inner"]["clip_names"] == [state["clip_names"][i] for i in failed0]
        assert state["stop_reason"] in ("max_primitives", "no_failures")
        # init "copy": primitive 1 continued primitive 0's observation statistics (its count includes them)
        n0 = load_checkpoint(workdir / "prim0" / "primitive.pt")["state_dict"]["obs_norm.count"]
        n1 = load_checkpoint(workdir / "prim1" / "primitive.pt")["state_dict"]["obs_norm.count"]
        assert float(n1) >= float(n0) + prims[1]["env_steps"]
    else:
        assert len(prims) == 1 and state["stop_reason"] == "no_failures"
    assert (workdir / "composer" / "policy.pt").is_file()
    report = (root / "runs" / "t" / "pmcp.md").read_text()
    assert "| walk |" in report and "| kick |" in report and "composite" in report

    # the final file: a phc checkpoint acting with the composite
    from mocap_phc.imitator import PHCParams, make_phc

    data = load_checkpoint(final)
    assert data["format"] == "mocap_phc.pmcp/1" and len(data["primitives"]) == len(prims) and data["composer_form"] == "weighted_sum"
    imitator = make_phc(PHCParams(action="residual"), skeleton=amp, checkpoint=final)
    assert isinstance(imitator, CompositeImitator) and imitator.num_primitives == len(prims)
    obs = torch.randn(3, imitator.obs_dim)
    pol = imitator.composite
    mu = torch.stack([p.mean_action(obs) for p in pol.primitives], -2)
    torch.testing.assert_close(imitator.policy_action(obs), compose(pol.composer.mean_action(obs), mu, "weighted_sum"))
    with pytest.raises(ValueError, match="observation dims"):
        make_phc(PHCParams(obs="keypoint"), skeleton=amp, checkpoint=final)

    out = root / "eval.json"
    result = invoke(["eval", final, "--json", out])
    assert result.exit_code == 0, result.output
    assert set(json.loads(out.read_text())["clips"]) == {"walk", "kick"}


def imitator_context(resolved, plugins, workdir, run_dir, stop, out):
    """(the imitator stage's context with the given ``stop`` and console file ``out``, its metrics log)."""
    from rich.console import Console

    from mocap.pipeline import StageContext, derive_seed
    from mocap.runlog import MetricsLogger

    log = MetricsLogger(run_dir / "metrics.jsonl", "imitator")
    ctx = StageContext(
        stage="imitator",
        resolved=resolved,
        plugins=plugins,
        workdir=workdir,
        run_dir=run_dir,
        upstream={},
        log=log,
        seed=derive_seed(resolved.spec.seed, "imitator"),
        device=torch.device("cpu"),
        console=Console(file=out, width=200),
        _stop=stop,
    )
    return ctx, log


def test_pmcp_resume_is_exact_in_every_phase(straight, tmp_path):
    """Ctrl-C (a stop after the 2nd should_stop call of each run) in every phase, rerun until done:
    the same primitives, composer and evaluations as the uninterrupted run."""
    from mocap.plugins import get_plugins
    from mocap.spec import load_spec_text

    _, final = straight
    plugins = get_plugins()
    resolved = load_spec_text(SPEC, plugins)
    workdir = tmp_path / "art"
    stops = []
    for _attempt in range(30):
        calls = {"n": 0}

        def stop(calls: dict[str, int] = calls) -> bool:
            calls["n"] += 1
            return calls["n"] >= 2

        ctx, log = imitator_context(resolved, plugins, workdir, tmp_path, stop, io.StringIO())
        result = ctx.build("imitator.trainer").run(ctx)
        log.close()
        state = json.loads((workdir / "pmcp_state.json").read_text())
        if state["phase"] == "done":
            break
        stops.append((state["phase"], len(state["primitives"]), state["primitives"][-1]["status"]))
    else:
        raise AssertionError("never finished")
    assert result.checkpoint == workdir / "pmcp.pt"
    assert ("primitives", 1, "training") in stops and ("composer", len(state["primitives"]), "frozen") in stops
    if len(state["primitives"]) > 1:
        assert ("primitives", 2, "training") in stops

    a, b = load_checkpoint(final), load_checkpoint(workdir / "pmcp.pt")
    for net_a, net_b in zip([*a["primitives"], a["composer"]], [*b["primitives"], b["composer"]]):
        assert net_a["config"] == net_b["config"]
        for key, va in net_a["state_dict"].items():
            vb = net_b["state_dict"][key]
            assert torch.equal(va, vb) if isinstance(va, torch.Tensor) else va == vb, key
    sa = json.loads((final.parent / "pmcp_state.json").read_text())
    assert sa["primitives"] == state["primitives"] and sa["final_evaluation"] == state["final_evaluation"]


RECOVERY_SPEC = SPEC.replace(
    "params: {action: residual, episode_steps: 20, eval_every: 0, energy_coef: 0.0}",
    "params: {action: residual, episode_steps: 20, eval_every: 0, energy_coef: 0.0, recovery_goal: {form: paper}}",
).replace(
    "      max_primitives: 2\n",
    "      max_primitives: 1\n      recovery: {clips: [walk], env_steps: 128,"
    " fail_states: {fall_init_prob: 0.5, far_init_prob: 0.5, recovery_episode_prob: 0.5, pool_size: 4, settle_steps: 10},"
    " composer_fail_states: {fall_init_prob: 0.5, pool_size: 4, settle_steps: 10}}\n",
)


def test_pmcp_recovery_primitive_joins_the_composer(tmp_path, amp):
    from mocap.testing import invoke
    from mocap_phc.imitator import PHCParams, make_phc

    assert "recovery:" in RECOVERY_SPEC and "recovery_goal" in RECOVERY_SPEC
    spec = tmp_path / "spec.yaml"
    spec.write_text(RECOVERY_SPEC)
    result = invoke(["run", spec, "--out", tmp_path / "runs" / "r"])
    assert result.exit_code == 0, result.output
    final = Path(json.loads((tmp_path / "runs" / "r" / "stages.json").read_text())[0]["checkpoint"])
    state = json.loads((final.parent / "pmcp_state.json").read_text())
    prims = state["primitives"]
    assert len(prims) == 2 and not prims[0].get("recovery") and prims[1]["recovery"] is True
    assert prims[1]["clip_ids"] == [0] and prims[1]["end"] == "budget"  # walk only; trained for its whole budget
    # P(F) started from the imitation primitive (init copy) and was trained with fallen/far starts
    env_state = load_checkpoint(final.parent / "prim1" / "ppo.pt")["env"]["inner"]
    assert "root_dist" in env_state
    data = load_checkpoint(final)
    assert len(data["primitives"]) == 2  # the composer mixes K + 1 = 2 primitives
    imitator = make_phc(PHCParams(action="residual", recovery_goal={"form": "paper"}), skeleton=amp, checkpoint=final)
    assert imitator.num_primitives == 2
    assert "(recovery)" in (tmp_path / "runs" / "r" / "pmcp.md").read_text()


def test_pmcp_recovery_needs_the_goal_switch(tmp_path):
    from mocap.testing import invoke

    spec = tmp_path / "spec.yaml"
    spec.write_text(RECOVERY_SPEC.replace(", recovery_goal: {form: paper}", ""))
    result = invoke(["run", spec, "--out", tmp_path / "runs" / "r"])
    assert result.exit_code != 0 and "recovery_goal" in (result.output + result.stderr)


def test_pmcp_primitive0_from_a_trained_imitator(straight, tmp_path):
    """`primitive0`: an existing policy becomes primitive 0 untrained (evaluated, frozen as 'given'),
    primitive 1 starts from it on the clips it fails; a policy of other sizes is a clear error."""
    from mocap.testing import invoke

    root, final = straight
    given = final.parent / "prim0" / "primitive.pt"
    spec = tmp_path / "spec.yaml"
    spec.write_text(SPEC.replace("      primitive_env_steps: 320\n", f"      primitive_env_steps: 320\n      primitive0: {given}\n"))
    result = invoke(["run", spec, "--out", tmp_path / "runs" / "g"])
    assert result.exit_code == 0, result.output
    stages = json.loads((tmp_path / "runs" / "g" / "stages.json").read_text())
    workdir = Path(stages[0]["checkpoint"]).parent
    state = json.loads((workdir / "pmcp_state.json").read_text())
    p0 = state["primitives"][0]
    assert p0["end"] == "given" and p0["env_steps"] == 0 and p0["source"] == str(given)
    assert not (workdir / "prim0" / "ppo.pt").exists()  # not trained
    a = load_checkpoint(workdir / "prim0" / "primitive.pt")["state_dict"]
    b = load_checkpoint(given)["state_dict"]
    tensors = [k for k in b if isinstance(b[k], torch.Tensor)]
    assert tensors and all(torch.equal(a[k], b[k]) for k in tensors)
    # the same policy, the same protocol: the same clips fail as in the run that trained it
    ref = json.loads((final.parent / "pmcp_state.json").read_text())["primitives"][0]["evaluation"]
    assert p0["evaluation"]["failed"] == ref["failed"]
    if p0["evaluation"]["failed"]:
        names = state["clip_names"]
        assert [names[i] for i in state["primitives"][1]["clip_ids"]] == p0["evaluation"]["failed"]
    # a policy with other hidden sizes
    bad = tmp_path / "bad.yaml"
    bad.write_text(
        spec.read_text().replace(
            "actor_hidden: [16], critic_hidden: [16], checkpoint_every: 2}", "actor_hidden: [8], critic_hidden: [16], checkpoint_every: 2}", 1
        )
    )
    result = invoke(["run", bad, "--out", tmp_path / "runs" / "b"])
    assert result.exit_code != 0 and "does not fit this imitator" in result.output and "Traceback" not in result.output


GETUP_SPEC = RECOVERY_SPEC.replace(
    " composer_fail_states:",
    " getup: {env_steps: 128, fail_states: {fall_init_prob: 1.0, pool_size: 4, settle_steps: 10},"
    " imitator: {amp: true, task_reward_weight: 0.0, amp_reward_weight: 1.0, amp_hidden: [16], amp_batch: 8}},"
    " composer_fail_states:",
)


def test_pmcp_getup_phase_runs_before_the_point_goal_phase(tmp_path):
    """[C]'s AMP-only get-up phase: trained first (fallen starts, AMP on), then P(F) starts from it."""
    from mocap.testing import invoke

    assert "getup:" in GETUP_SPEC
    spec = tmp_path / "spec.yaml"
    spec.write_text(GETUP_SPEC)
    result = invoke(["run", spec, "--out", tmp_path / "runs" / "r"])
    assert result.exit_code == 0, result.output
    final = Path(json.loads((tmp_path / "runs" / "r" / "stages.json").read_text())[0]["checkpoint"])
    work = final.parent
    pf = json.loads((work / "pmcp_state.json").read_text())["primitives"][1]
    assert pf["recovery"] is True and pf["getup"]["status"] == "done" and pf["getup"]["env_steps"] >= 128
    getup_env = load_checkpoint(work / "prim1_getup" / "ppo.pt")["env"]["inner"]
    pf_env = load_checkpoint(work / "prim1" / "ppo.pt")["env"]["inner"]
    assert "amp" in getup_env and "amp" not in pf_env  # the discriminator lives in the get-up phase only
    assert (work / "prim1_getup" / "primitive.pt").is_file()
    lines = [json.loads(x) for x in (tmp_path / "runs" / "r" / "metrics.jsonl").read_text().splitlines() if x.strip()]
    getup_lines = [x for x in lines if x.get("stage") == "imitator/prim1_getup"]
    # task weight 0, AMP weight 1 (energy_coef 0 here): the reward is the AMP reward alone
    assert getup_lines and all(x["reward_mean"] == pytest.approx(x["env/reward/amp"], rel=1e-5) for x in getup_lines)
    assert any(x["env/reward/task"] > 0 for x in getup_lines)
    assert "get-up phase" in (tmp_path / "runs" / "r" / "pmcp.md").read_text()


def test_pmcp_getup_params_are_the_codes_phase_one():
    from mocap.errors import UserError
    from mocap_phc.imitator import PHCParams
    from mocap_phc.pmcp import GetupPhaseParams, PMCPParams, PMCPTrainer, RecoveryPhaseParams

    g = GetupPhaseParams()
    assert g.fail_states.fall_init_prob == 1.0 and g.fail_states.far_init_prob == 0.0 and g.fail_states.recovery_episode_prob == 0.0
    overrides = {"amp": True, "task_reward_weight": 0.0, "amp_reward_weight": 1.0, "amp_hidden": [8]}
    trainer = PMCPTrainer(PMCPParams(recovery=RecoveryPhaseParams(getup=GetupPhaseParams(imitator=overrides))))
    trainer.component = type("C", (), {"params": PHCParams(recovery_goal={"form": "paper"}, energy_coef=0.0)})()
    got = trainer._getup_params()
    assert isinstance(got, PHCParams)
    assert got.amp and got.task_reward_weight == 0.0 and got.amp_reward_weight == 1.0 and got.amp_hidden == [8]
    assert got.fail_states is not None and got.fail_states.fall_init_prob == 1.0
    assert got.recovery_goal is not None and got.recovery_goal.form == "paper"
    bad = PMCPTrainer(PMCPParams(recovery=RecoveryPhaseParams(getup=GetupPhaseParams(imitator={"amp_lr": -1.0}))))
    bad.component = trainer.component
    with pytest.raises(UserError, match="recovery.getup.imitator"):  # validated as the imitator's params: one error line
        bad._getup_params()
    # the default overrides drop get-up starts (they track a get-up clip, which AMP excludes)
    base = PHCParams(recovery_goal={"form": "paper"}, energy_coef=0.0, fail_states={"fall_init_prob": 0.1}, getup_starts={"clips": ["getup*"]})
    default = PMCPTrainer(PMCPParams(recovery=RecoveryPhaseParams(getup=GetupPhaseParams())))
    default.component = type("C", (), {"params": base})()
    got = default._getup_params()
    assert got.amp and got.getup_starts is None


def test_pmcp_phases_continue_one_discriminator(tmp_path):
    """[P] §4.2 / [C]: with AMP on, the discriminator is fine-tuned across phases, not re-initialized:
    the composer's discriminator has every update of the last primitive's plus its own."""
    from mocap.testing import invoke

    spec = tmp_path / "spec.yaml"
    spec.write_text(
        SPEC.replace("energy_coef: 0.0}", "energy_coef: 0.0, amp: true, amp_hidden: [16], amp_batch: 8}", 1).replace("max_primitives: 2", "max_primitives: 1")
    )
    result = invoke(["run", spec, "--out", tmp_path / "runs" / "t"])
    assert result.exit_code == 0, result.output
    work = Path(json.loads((tmp_path / "runs" / "t" / "stages.json").read_text())[0]["checkpoint"]).parent
    prim = load_checkpoint(work / "prim0" / "ppo.pt")
    comp = load_checkpoint(work / "composer" / "ppo.pt")
    prim_updates = prim["env"]["inner"]["amp"]["trainer"]["updates"]
    comp_updates = comp["env"]["amp"]["trainer"]["updates"]
    assert prim_updates > 0 and comp_updates > prim_updates, (prim_updates, comp_updates)
    assert "discriminator continues from prim0" in result.output


def test_pmcp_subsets_without_a_getup_clip_drop_getup_starts(tmp_path):
    """With the imitator's ``getup_starts``, PMCP's envs on clip subsets that hold no get-up clip (the
    one-clip probe, per-subset evaluations, P(F)'s walk-only set here) train and evaluate without those
    starts instead of failing; the full motion set keeps them (it has the get-up clip)."""
    from mocap.testing import invoke

    text = RECOVERY_SPEC.replace("clips: [walk, kick]}", "clips: [walk, kick, getup_faceup]}").replace(
        "recovery_goal: {form: paper}}",
        "recovery_goal: {form: paper}, fail_states: {fall_init_prob: 0.5, pool_size: 4, settle_steps: 10}, getup_starts: {clips: ['getup*']}}",
    )
    assert "getup_starts" in text and "getup_faceup" in text
    spec = tmp_path / "spec.yaml"
    spec.write_text(text)
    result = invoke(["run", spec, "--out", tmp_path / "runs" / "r"])
    assert result.exit_code == 0, result.output
    final = Path(json.loads((tmp_path / "runs" / "r" / "stages.json").read_text())[0]["checkpoint"])
    prims = json.loads((final.parent / "pmcp_state.json").read_text())["primitives"]
    assert prims[1]["recovery"] is True and prims[1]["clip_ids"] == [0]  # P(F) on walk alone
