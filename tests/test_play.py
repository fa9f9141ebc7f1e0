"""Watching a policy (``mocap play``) and its headless twin (``mocap render TARGET``): the no-display
message, the key state machine, the viewer loop driven by a fake viewer, and a policy video."""

from __future__ import annotations

import contextlib
import os
from pathlib import Path

os.environ.setdefault("MUJOCO_GL", "egl")

import pytest  # noqa: E402
import torch  # noqa: E402

from mocap.interfaces import Box  # noqa: E402
from mocap.play import SPEEDS, PlayControls, Player, display_available, draw_reference, run_viewer, speed_label  # noqa: E402
from mocap.plugins import get_plugins  # noqa: E402
from mocap.testing import invoke  # noqa: E402

SPEC = """\
spec_version: 1
name: play-tiny
humanoid: {name: amp}
motions: {name: deepmimic, params: {clips: [walk, kick]}}
simulator: {name: mujoco}
imitator:
  name: phc
  params: {action: residual}
  trainer: {name: ppo}
"""


@pytest.fixture(scope="module")
def policy_file(tmp_path_factory) -> Path:
    """A tiny PHC policy with a zero action head (residual 0: PD replay of the reference), its spec embedded."""
    from mocap.rl.networks import ActorCritic, save_policy
    from mocap.spec import load_spec_text

    plugins = get_plugins()
    resolved = load_spec_text(SPEC, plugins)
    phc = plugins.get("imitator", "phc").build(resolved.params["imitator"], skeleton=plugins.get("humanoid", "amp").build({}))
    torch.manual_seed(0)
    model = ActorCritic(phc.observation.dim(15), Box((28,)), [16], [16], "elu", -5.0, False, True, 5.0, False)
    for p in model.action_head.parameters():
        torch.nn.init.zeros_(p)
    path = tmp_path_factory.mktemp("play") / "policy.pt"
    save_policy(path, model, spec_yaml=resolved.to_yaml())
    return path


@pytest.fixture(scope="module")
def loaded(policy_file):
    from mocap.eval_targets import build_evaluation_target, load_evaluation_target

    plugins = get_plugins()
    return build_evaluation_target(load_evaluation_target(policy_file, plugins), plugins)


# ------------------------------------------------------------------------------ no display
def test_play_without_a_display_says_so_in_one_line_and_points_to_render(tmp_path, monkeypatch):
    monkeypatch.delenv("DISPLAY", raising=False)
    monkeypatch.delenv("WAYLAND_DISPLAY", raising=False)
    result = invoke(["play", tmp_path / "policy.pt"])
    assert result.exit_code == 2 and "Traceback" not in result.output
    lines = [line for line in result.stderr.splitlines() if line.strip()]
    assert len(lines) <= 2, result.stderr  # one message (rich may wrap it once)
    assert "needs a display" in result.stderr and "mocap render" in result.stderr
    ok, why = display_available({}, "linux")
    assert not ok and "DISPLAY" in why
    assert display_available({"WAYLAND_DISPLAY": "wayland-0"}, "linux")[1] != "no display (DISPLAY and WAYLAND_DISPLAY are unset)"


# ----------------------------------------------------------------------------- key handling
def test_keys_drive_the_state_machine():
    c = PlayControls(num_clips=3)
    assert c.speed == 1.0 and not c.paused and c.mode == "imitate"
    assert c.press(32) == "pause" and c.paused
    assert c.press(" ") == "pause" and not c.paused
    assert c.press("]") == "faster" and c.speed == 2.0
    for _ in range(5):
        c.press(ord("]"))
    assert c.speed == SPEEDS[-1] == 4.0  # clamped
    for _ in range(20):
        c.press("[")
    assert c.speed == SPEEDS[0] == 1 / 16 and speed_label(c.speed) == "1/16x"
    assert c.press("n") == "next" and c.clip == 1 and c.restart
    c.restart = False
    c.press("P"), c.press("P")
    assert c.clip == 2 and c.restart  # wraps around
    c.restart = False
    assert c.press("G") is None and c.mode == "imitate" and "no latent prior" in c.message and not c.restart
    assert c.press("R") == "reset" and c.restart and c.message == ""
    assert c.press("X") is None and c.clip == 2 and c.speed == 1 / 16  # other keys do nothing
    g = PlayControls(num_clips=2, can_generate=True)
    assert g.press("G") == "generate" and g.mode == "generate" and g.restart
    assert g.press("N") == "next" and g.mode == "imitate" and g.clip == 1  # N/P go back to imitating


def test_player_rolls_out_exactly_like_the_evaluation(loaded):
    """Imitate mode is :func:`mocap.imitation_eval.rollout_imitation` (what ``render`` records)."""
    from mocap.imitation_eval import rollout_imitation

    player = Player(loaded, loaded.make_sim(1), clip="walk")
    for _ in range(6):
        player.step()
    sim = loaded.make_sim(1)
    ids = torch.tensor([loaded.library.clip_index("walk")])
    ref = rollout_imitation(sim, loaded.library, loaded.policy, ids, torch.tensor([6]), threshold=float("inf"))
    assert torch.allclose(player.state.body_pos.float().cpu()[0], ref.traj.sim[6, 0], atol=1e-6)
    assert player.steps == 6 and player.reference_positions().shape == (loaded.skeleton.num_bodies, 3)


class FakeViewer:
    """The passive viewer's interface (is_running, lock, sync, user_scn); presses scripted keys."""

    def __init__(self, player, model, frames: int, script: dict[int, str]):
        import mujoco

        self.player, self.frames, self.script = player, frames, script
        self.user_scn = mujoco.MjvScene(model, maxgeom=64)
        self.synced: list[tuple[int, int, bool, float]] = []

    def is_running(self) -> bool:
        return len(self.synced) < self.frames

    def lock(self):
        return contextlib.nullcontext()

    def sync(self) -> None:
        c = self.player.controls
        self.synced.append((self.player.total_steps, c.clip, c.paused, c.speed))
        for key in self.script.get(len(self.synced), ""):
            self.player.key_callback(ord(key))


class FakeClock:
    def __init__(self):
        self.t = 0.0

    def __call__(self) -> float:
        return self.t

    def sleep(self, s: float) -> None:
        self.t += s


def test_viewer_loop_paces_steps_and_applies_keys(loaded):
    import mujoco

    sim = loaded.make_sim(1)
    player = Player(loaded, sim, clip="walk")
    data = mujoco.MjData(sim.model)
    # keys pressed after frame n's sync act from frame n + 1 on: pause after frame 2, resume at
    # half speed after frame 5, next clip after frame 9
    script = {3: " ", 6: " [", 10: "N"}
    viewer = FakeViewer(player, sim.model, frames=12, script=script)
    clock = FakeClock()
    statuses: list[str] = []
    frames = run_viewer(player, viewer, data, clock=clock, sleep=clock.sleep, on_status=statuses.append)
    assert frames == 12
    steps = [s[0] for s in viewer.synced]
    # frame 0: no time has passed; then one control step per 1/30 s frame at 1x, none while
    # paused, one every other frame at 1/2x
    assert steps == [0, 1, 2, 2, 2, 2, 2, 3, 3, 4, 4, 5]
    assert [s[2] for s in viewer.synced] == [False] * 3 + [True] * 3 + [False] * 6
    assert viewer.synced[5][3] == 1.0 and viewer.synced[6][3] == 0.5
    assert viewer.synced[9][1] == 0 and viewer.synced[10][1] == 1 and player.clip_name == "kick"
    assert player.steps == 1  # N restarted the episode on the next clip
    assert any("paused" in s for s in statuses) and any("kick" in s for s in statuses)
    # the viewer shows the simulator's env 0 and the reference as spheres
    assert viewer.user_scn.ngeom == loaded.skeleton.num_bodies
    assert abs(float(data.qpos[2]) - float(player.state.root_pos[0, 2])) < 1e-6
    assert draw_reference(viewer.user_scn, None) == 0


def test_generate_mode_samples_the_prior_without_a_reference(loaded):
    from dataclasses import replace

    from mocap_pulse.latent import PulseParams, make_pulse

    latent = make_pulse(PulseParams(latent_dim=4, encoder_hidden=[8], prior_hidden=[8], decoder_hidden=[8]), skeleton=loaded.skeleton)
    target = replace(loaded, latent=latent, label="pd_targets")
    player = Player(target, loaded.make_sim(1), generate=True, seed=3, horizon=0.1)
    assert player.controls.can_generate and player.controls.mode == "generate"
    start = player.state.root_pos.clone()
    player.step(), player.step()
    assert player.reference_positions() is None and player.steps == 2 and not torch.equal(player.state.root_pos, start)
    player.step()  # 3 steps = 0.1 s: a new prior sample
    assert player.episodes == 2 and player.steps == 0
    player.key_callback(ord("N"))
    assert player.process_keys() == ["next"] and player.controls.mode == "imitate"
    with pytest.raises(Exception, match="no latent space"):
        Player(loaded, loaded.make_sim(1), generate=True)


# ------------------------------------------------------------------------------ headless video
def test_render_writes_the_policy_rollout_as_a_video(policy_file, tmp_path):
    import imageio.v3 as iio

    out = tmp_path / "walk.gif"
    result = invoke(["render", policy_file, "--clip", "walk", "--seconds", "0.2", "--width", "96", "--height", "64", "--out", out])
    if result.exit_code == 2 and "OpenGL" in result.stderr:
        pytest.skip(f"no offscreen OpenGL: {result.stderr}")
    assert result.exit_code == 0, result.output
    assert out.stat().st_size > 0 and "clip walk" in result.stdout
    assert iio.imread(out).shape[:3] == (6, 64, 96)  # 0.2 s at 30 Hz
    both = invoke(["render", policy_file, "--motion", "walk"])
    assert both.exit_code == 2 and "not both" in both.stderr
    gen = invoke(["render", policy_file, "--generate", "--out", tmp_path / "g.mp4"])
    assert gen.exit_code == 2 and "no latent space" in gen.stderr and "Traceback" not in gen.output
    assert invoke(["render"]).exit_code == 2


def test_play_opens_the_passive_viewer_where_a_display_exists(policy_file, monkeypatch):
    """``play`` with a display: launch_passive (faked here) gets the simulator's model and the key
    callback; the camera tracks the humanoid; a viewer that cannot open is one clean error."""
    import mujoco
    import mujoco.viewer

    from mocap.play import play

    launched = {}

    class Handle(FakeViewer):
        def __init__(self, model, data, *, key_callback, show_left_ui, show_right_ui):
            self.key_callback, self.synced, self.frames = key_callback, [], 4
            self.user_scn = mujoco.MjvScene(model, maxgeom=64)
            self.cam = mujoco.MjvCamera()
            launched.update(model=model, data=data, handle=self)

        def sync(self):
            self.synced.append(1)
            if len(self.synced) == 1:
                self.key_callback(ord("]"))

        def __enter__(self):
            return self

        def __exit__(self, *exc):
            launched["closed"] = True

    monkeypatch.setattr(mujoco.viewer, "launch_passive", Handle)
    frames = play(policy_file, clip="kick", environ={"DISPLAY": ":0"})
    assert frames == 4 and launched["closed"] and launched["model"].nbody > 10
    model, cam = launched["model"], launched["handle"].cam
    assert cam.type == mujoco.mjtCamera.mjCAMERA_TRACKING and cam.trackbodyid == int(model.jnt_bodyid[0])  # the root's free joint
    assert launched["data"].qpos[2] > 0.5  # the simulator's state was written into the viewer's data

    def no_window(*args, **kwargs):
        raise RuntimeError("`launch_passive` requires that the Python script be run under `mjpython` on macOS")

    monkeypatch.setattr(mujoco.viewer, "launch_passive", no_window)
    monkeypatch.setenv("DISPLAY", ":0")
    result = invoke(["play", policy_file])
    assert result.exit_code == 2 and "Traceback" not in result.output
    assert "cannot open the MuJoCo viewer" in result.stderr and "mocap render" in result.stderr


def test_generate_falls_back_to_imitating_when_the_latent_needs_a_reference(loaded):
    """A decoder trained on a residual teacher's raw output cannot act without a reference."""
    from dataclasses import replace

    from mocap_pulse.latent import PulseParams, make_pulse

    latent = make_pulse(PulseParams(latent_dim=4, encoder_hidden=[8], prior_hidden=[8], decoder_hidden=[8]), skeleton=loaded.skeleton)
    target = replace(loaded, latent=latent, label="policy_output")  # to_pd_targets needs the reference: refused
    player = Player(target, loaded.make_sim(1), clip="walk")
    player.key_callback(ord("G"))
    assert player.process_keys() == ["generate"] and player.controls.mode == "generate"
    player.step()
    assert player.controls.mode == "imitate" and "cannot generate" in player.controls.message and player.steps == 0
    player.advance(2 * player.dt)
    assert player.steps == 2 and player.controls.mode == "imitate"
