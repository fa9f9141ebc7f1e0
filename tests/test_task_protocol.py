"""The task protocol switches of issue 65: the official code's fall rule (a non-foot contact AND a
low non-foot body, not in an episode's first two steps) beside this project's (contact OR a low root)."""

from __future__ import annotations

import dataclasses

import pytest
import torch

from mocap.plugins import get_plugins
from mocap.testing import fake_sim_state


@pytest.mark.parametrize("task_name", ["speed", "reach", "strike"])
def test_fall_rules_differ_exactly_where_the_code_and_this_project_differ(amp, task_name: str) -> None:  # type: ignore[no-untyped-def]
    comp = get_plugins().get("task", task_name)
    ours = comp.build(None, skeleton=amp, num_envs=4, device="cpu")
    code = comp.build(comp.validate_params({"termination": {"rule": "contact_and_low_body"}}), skeleton=amp, num_envs=4, device="cpu")
    state = fake_sim_state(amp, 4)  # standing, root at 0.9 m
    hand = amp.body_names.index("right_hand")
    contact = torch.zeros(4, amp.num_bodies, dtype=torch.bool)
    contact[0, hand] = True  # env 0: a hand touches the ground, every body high (a hand on a wall, a stumble)
    contact[1, hand] = True  # env 1: the hand touches and lies on the ground
    body = state.body_pos.clone()
    body[1, hand, 2] = 0.05
    body[2, :, 2] = body[2, :, 2] - 0.85  # env 2: everything low, no contact reported (root at 0.05 m)
    state = dataclasses.replace(state, body_pos=body, root_pos=body[:, 0].clone(), body_contact=contact)
    for task in (ours, code):
        task.progress[:] = 5  # mid-episode
    assert ours.terminated(state).tolist() == [True, True, True, False]  # contact OR a low root
    assert code.terminated(state).tolist() == [False, True, False, False]  # contact AND a low body
    code.progress[:] = 1  # the code ignores falls in an episode's first two steps
    assert code.terminated(state).tolist() == [False, False, False, False]
