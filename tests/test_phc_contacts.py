"""Per-clip contact rules of the PHC imitation env (PHCParams.contact_rules): which bodies may touch
the ground in which clip; any other contact terminates the episode as a fall."""

from __future__ import annotations

from dataclasses import replace

import pytest
import torch
from hypothesis import given, settings
from hypothesis import strategies as st

from mocap.testing import fake_sim_state
from mocap_phc.phc_params import ContactRules, PHCParams
from mocap_phc.termination import Termination, contact_table

CLIPS = ["walk", "cartwheel", "roll", "getup_faceup", "getup_facedown"]
RULES = {"cartwheel": ["*_foot", "*_hand"], "roll": ["*"], "getup_*": ["*"]}


def test_contact_table_takes_the_first_matching_clip_glob_and_defaults_to_the_feet(amp):
    table = contact_table(amp, CLIPS, RULES)
    names = list(amp.body_names)
    allowed = {c: {b for b, f in zip(names, table[i].tolist()) if not f} for i, c in enumerate(CLIPS)}
    assert allowed["walk"] == set(amp.feet)
    assert allowed["cartwheel"] == {"right_foot", "left_foot", "right_hand", "left_hand"}
    assert allowed["roll"] == set(names) and allowed["getup_faceup"] == set(names) == allowed["getup_facedown"]
    first = contact_table(amp, ["getup_faceup"], {"getup_*": ["*_foot"], "getup_faceup": ["*"]})
    assert first[0].sum() == amp.num_bodies - 2  # the first key wins, not the most specific
    assert contact_table(amp, ["walk"], {}, default=["*"]).sum() == 0


def test_a_body_glob_matching_no_body_is_an_error_naming_it(amp):
    with pytest.raises(ValueError, match="no body of the skeleton matches 'right_palm'"):
        contact_table(amp, CLIPS, {"cartwheel": ["right_palm"]})


@settings(max_examples=40, deadline=None)
@given(data=st.data())
def test_the_forbidden_bodies_are_exactly_the_complement_of_the_allowed_ones(amp, data):
    names = list(amp.body_names)
    allowed = data.draw(st.lists(st.sampled_from(names), min_size=1, unique=True))
    row = contact_table(amp, ["c"], {"c": allowed})[0]
    assert {b for b, f in zip(names, row.tolist()) if not f} == set(allowed)


def test_a_forbidden_contact_terminates_as_a_fall_and_an_allowed_one_does_not(amp):
    term = Termination.for_skeleton(amp)
    table = contact_table(amp, CLIPS, RULES)
    state = fake_sim_state(amp, 3)
    hand = amp.body_index("right_hand")
    contact = torch.zeros(3, amp.num_bodies, dtype=torch.bool)
    contact[:, hand] = True  # every env touches the ground with its right hand
    state = replace(state, body_contact=contact)
    clip_ids = torch.tensor([0, 1, 2])  # walk (feet only), cartwheel (hands allowed), roll (anything)
    _, parts = term(state, state, None, table[clip_ids])
    assert parts["fall"].tolist() == [True, False, False]
    assert not bool(parts["tracking"].any())  # the reference is the state itself
    _, parts = term(state, state, None, table[clip_ids], forbidden_height=0.05)  # the hand is higher than 5 cm
    assert parts["fall"].tolist() == [False, False, False]
    _, parts = term(state, state)  # no rules, no fall_check: PHC never terminates on contacts
    assert parts["fall"].tolist() == [False, False, False]


def test_contact_rules_are_validated_as_part_of_the_params():
    p = PHCParams.model_validate({"contact_rules": {"allowed": RULES, "fall_height": 0.15}})
    assert isinstance(p.contact_rules, ContactRules) and p.contact_rules.allowed["roll"] == ["*"]
    with pytest.raises(ValueError, match="extra"):
        PHCParams.model_validate({"contact_rules": {"alowed": RULES}})


def test_the_env_ends_crawl_episodes_on_a_knee_contact_unless_the_clip_allows_it(amp):
    """End to end in the imitation env: the crawl reference touches the ground with more than the
    feet, so with the default (feet only) its episodes end as falls; allowing every body for crawl
    removes exactly those terminations."""
    from mocap.motion.deepmimic import DeepMimicParams, DeepMimicSource
    from mocap.motion.library import MotionLibrary
    from mocap_phc.env import ImitationEnv
    from mocap_sim_mujoco.simulator import MujocoSimulator

    crawl = DeepMimicSource(DeepMimicParams(clips=["crawl"])).load(amp)

    def falls(rules: dict) -> float:
        params = PHCParams(action="residual", contact_rules=rules, start_sampling={"mode": "uniform"})
        env = ImitationEnv(params, amp, MotionLibrary(crawl, amp), MujocoSimulator(None, skeleton=amp, num_envs=8, seed=0), seed=0)
        env.reset()
        total = 0.0
        for _ in range(10):
            total += float(env.step(torch.zeros(8, amp.num_dofs)).info["terminated/fall"].sum())
        env.close()
        return total

    assert falls({}) > 0
    assert falls({"allowed": {"crawl": ["*"]}}) == 0
