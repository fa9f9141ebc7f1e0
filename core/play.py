"""Watching a policy: ``mocap play TARGET`` (MuJoCo's interactive viewer) and the policy modes of
``mocap render TARGET`` (the same rollouts written to an MP4 / GIF, headless).

``TARGET`` is anything ``mocap eval`` accepts (:func:`mocap.eval_targets.load_evaluation_target`): a
``policy.pt`` / ``latent.pt``, a checkpoint directory, a run directory or a spec. One simulator env
is rolled out by a :class:`Player`, which holds all the stepping logic and knows nothing of windows:

* **imitate** (default): the policy (a latent space as an imitator, ``z`` = encoder mean, or the
  imitator itself) tracks a clip from its first frame, exactly as
  :func:`mocap.imitation_eval.rollout_imitation` does; the episode restarts at the end of the clip
  (looping clips: after ``horizon`` seconds);
* **generate** (``G``; needs a latent space with ``random_action``): random motion from the latent
  prior without a reference, as :func:`mocap.generation_eval.evaluate_generation` does (a start state
  drawn from the motion library, proprioception-only observations, the prior's action decoded to PD
  targets); a new sample every ``horizon`` seconds.

:class:`PlayControls` is the key state machine (space pause, ``[`` / ``]`` slower / faster, ``N`` /
``P`` next / previous clip, ``R`` restart the episode, ``G`` a new sample from the prior) and
:func:`run_viewer` the real-time loop around any object with the passive viewer's interface
(``is_running``, ``lock``, ``sync``, ``user_scn``), so both are tested without a display.
``mocap play`` opens ``mujoco.viewer.launch_passive`` when a display exists, and otherwise says so
in one line and points to ``mocap render``. The command is registered by the ``mujoco`` simulator
plugin next to ``mocap render`` (:mod:`mocap_sim_mujoco.commands`): the viewer is MuJoCo's.

``mocap render RUN_DIR`` of a run with a trained ``task`` stage records the task policy acting through
its latent space instead (:mod:`mocap.task_video`).

``mocap render TARGET --clip C`` writes the imitate rollout with
:func:`mocap.imitation_eval.record_video` (the reference drawn as a ghost); ``--generate`` records a
:class:`Player` rollout from the prior (same seed, same rollout as pressing ``G`` once in ``play``)
with the simulator's video recorder.
"""

from __future__ import annotations

import math
import os
import queue
import sys
import time
from dataclasses import dataclass
from pathlib import Path
from typing import Any, Callable, Protocol, runtime_checkable

import torch


@runtime_checkable
class MujocoBacked(Protocol):
    """A simulator the interactive viewer can show: a MuJoCo model and each env's state written
    into an ``MjData`` (the ``mujoco`` simulator; ``mujoco_warp`` too)."""

    model: Any

    def write_mjdata(self, env_id: int, data: Any) -> Any: ...


#: slow-motion factors selectable with [ and ]
SPEEDS = (1 / 16, 1 / 8, 1 / 4, 1 / 2, 1.0, 2.0, 4.0)

#: GLFW key codes (what the viewer's key callback receives; letters are their upper-case ASCII) -> action
KEYS = {32: "pause", ord("["): "slower", ord("]"): "faster", ord("N"): "next", ord("P"): "previous", ord("R"): "reset", ord("G"): "generate"}

HELP = "space pause · [ ] slower/faster · N/P next/previous clip · R restart · G sample the latent prior"


def key_code(key: int | str) -> int:
    """A GLFW key code from an int (as is) or a one-character string (case-insensitive)."""
    if isinstance(key, str):
        if len(key) != 1:
            raise ValueError(f"one character expected, got {key!r}")
        return ord(key.upper())
    return int(key)


@dataclass
class PlayControls:
    """The viewer's state: which clip, mode, speed, paused; :meth:`press` applies one key."""

    num_clips: int
    clip: int = 0
    speed_index: int = SPEEDS.index(1.0)
    paused: bool = False
    mode: str = "imitate"  # or "generate"
    can_generate: bool = False
    restart: bool = False  # the episode must restart (set by N, P, R, G; cleared by the player)
    message: str = ""

    @property
    def speed(self) -> float:
        return SPEEDS[self.speed_index]

    def press(self, key: int | str) -> str | None:
        """Apply one key; returns the action it triggered, or None for keys that do nothing here."""
        action = KEYS.get(key_code(key))
        self.message = ""
        if action == "pause":
            self.paused = not self.paused
        elif action == "slower":
            self.speed_index = max(0, self.speed_index - 1)
        elif action == "faster":
            self.speed_index = min(len(SPEEDS) - 1, self.speed_index + 1)
        elif action in ("next", "previous"):
            step = 1 if action == "next" else -1
            self.clip = (self.clip + step) % self.num_clips
            self.mode = "imitate"
            self.restart = True
        elif action == "reset":
            self.restart = True
        elif action == "generate":
            if self.can_generate:
                self.mode = "generate"
                self.restart = True
            else:
                self.message = "G: this target has no latent prior to sample (random_action)"
                return None
        return action


class Player:
    """Rolls one simulator env out under :class:`PlayControls` (module docstring).

    Args:
        loaded: the built target (:func:`mocap.eval_targets.build_evaluation_target`).
        sim: a one-env simulator of the target (``loaded.make_sim(1)``).
        clip: the clip to start with (default: the first).
        generate: start in generate mode.
        noise: prior noise scale in generate mode.
        seed: seed of the generate mode's start states and prior noise.
        horizon: seconds per episode for looping clips and prior samples.
        max_steps_per_advance: real-time catch-up limit (control steps per :meth:`advance`).
    """

    def __init__(
        self,
        loaded: Any,
        sim: Any,
        *,
        clip: str | None = None,
        generate: bool = False,
        noise: float = 1.0,
        seed: int = 0,
        horizon: float = 10.0,
        max_steps_per_advance: int = 4,
    ):
        self.loaded, self.sim, self.lib = loaded, sim, loaded.library
        self.dt = float(sim.dt)
        self.noise, self.horizon, self.max_steps = float(noise), float(horizon), int(max_steps_per_advance)
        self.generator = torch.Generator().manual_seed(int(seed))
        latent = loaded.latent
        can_generate = latent is not None and latent.samples_prior
        self.controls = PlayControls(self.lib.num_clips, can_generate=can_generate)
        if clip is not None:
            self.controls.clip = self._clip_index(clip)
        if generate:
            if not can_generate:
                from mocap.errors import UserError

                raise UserError("--generate: the target has no latent space with a prior to sample (random_action)")
            self.controls.mode = "generate"
        self.keys: queue.Queue[int] = queue.Queue()
        self.budget = 0.0
        self.steps = 0  # control steps of the current episode
        self.total_steps = 0
        self.episodes = 0
        self.reset()

    def _clip_index(self, name: str) -> int:
        try:
            return self.lib.clip_index(name)
        except KeyError as exc:
            from mocap.errors import UserError

            raise UserError(str(exc.args[0])) from None

    # ------------------------------------------------------------------------------ keys
    def key_callback(self, keycode: int) -> None:
        """The viewer's key callback (runs on the viewer's thread): queue the key for the loop."""
        self.keys.put(int(keycode))

    def process_keys(self) -> list[str]:
        """Apply the queued keys; restart the episode when one asked for it. Returns the actions."""
        actions = []
        while True:
            try:
                key = self.keys.get_nowait()
            except queue.Empty:
                break
            action = self.controls.press(key)
            if action:
                actions.append(action)
        if self.controls.restart:
            self.reset()
        return actions

    # ---------------------------------------------------------------------------- stepping
    @property
    def clip_name(self) -> str:
        return self.lib.clip_names[self.controls.clip]

    def episode_seconds(self) -> float:
        """Length of the current episode: the clip's duration (looping clips and prior samples: ``horizon``)."""
        c = self.controls.clip
        if self.controls.mode == "generate" or bool(self.lib.loops[c]):
            return self.horizon
        return float(self.lib.durations[c])

    def reset(self) -> None:
        """Start the current mode's episode: the clip from its first frame, or a new start state from the library."""
        self.controls.restart = False
        self.steps, self.budget = 0, 0.0
        self.episodes += 1
        if self.controls.mode == "generate":
            from mocap.generation_eval import start_states

            ids, times = start_states(self.lib, 1, self.sim.skeleton, 0.25, self.generator)
        else:
            ids = torch.tensor([self.controls.clip])
            times = torch.zeros(1, dtype=self.lib.dtype, device=self.lib.device)
        self.clip_ids = ids
        self.ref = self.lib.frames(ids, times)
        self.sim.reset(torch.arange(1), self.ref)
        self.state = self.sim.state

    def step(self) -> None:
        """One control step of the current mode (restarts the episode after it ends)."""
        if self.controls.mode == "generate":
            if not self._step_generate():
                return  # the latent cannot act without a reference: back to imitating, restarted
        else:
            self._step_imitate()
        self.steps += 1
        self.total_steps += 1
        if self.steps * self.dt >= self.episode_seconds() - 1e-9:
            self.reset()

    def _step_imitate(self) -> None:
        # as mocap.imitation_eval.rollout_imitation: the reference of the step being taken, t = (k + 1) dt
        policy = self.loaded.policy
        t = torch.full((1,), (self.steps + 1) * self.dt, dtype=self.lib.dtype, device=self.lib.device)
        self.ref = self.lib.frames_ahead(self.clip_ids, t, self.dt, policy.reference_steps)
        with torch.no_grad():
            actions = policy.act(policy.observe(self.state, self.ref))
        self.state = self.sim.step(actions)

    def _step_generate(self) -> bool:
        # as mocap.generation_eval.evaluate_generation: proprioception only, the prior's action as PD targets
        from mocap.generation_eval import _reference_free

        obs = _reference_free(self.loaded.imitator.observe(self.state, self.ref))
        with torch.no_grad():
            out = self.loaded.latent.random_action(obs, noise_scale=self.noise, generator=self.generator)
            try:
                targets = self.loaded.to_pd_targets(obs, out)
            except ValueError as exc:
                self.controls.mode = "imitate"
                self.controls.message = f"G: cannot generate ({exc}); the latent needs label: pd_targets or an absolute-action imitator"
                self.reset()
                return False
        self.state = self.sim.step(targets)
        return True

    def advance(self, wall_seconds: float) -> int:
        """Step as many control steps as ``wall_seconds`` of real time hold at the current speed
        (none while paused; at most ``max_steps_per_advance``, the rest is dropped). Returns the steps taken."""
        if self.controls.paused:
            self.budget = 0.0
            return 0
        self.budget += max(0.0, float(wall_seconds)) * self.controls.speed
        n = int(math.floor(self.budget / self.dt + 1e-9))
        if n > self.max_steps:
            n, self.budget = self.max_steps, 0.0
        else:
            self.budget -= n * self.dt
        for _ in range(n):
            self.step()
        return n

    def reference_positions(self) -> Any:
        """(B, 3) body positions of the reference (imitate mode), else None."""
        if self.controls.mode != "imitate":
            return None
        return self.ref.body_pos[0].detach().float().cpu().numpy()

    def status(self) -> str:
        c = self.controls
        what = f"clip {self.clip_name} ({c.clip + 1}/{c.num_clips})" if c.mode == "imitate" else f"prior sample #{self.episodes} (noise {self.noise:g})"
        parts = [what, f"speed {speed_label(c.speed)}"]
        if c.paused:
            parts.append("paused")
        if c.message:
            parts.append(c.message)
        return " | ".join(parts)


def speed_label(speed: float) -> str:
    """``1/4x``, ``2x``: a playback speed as shown to the user."""
    return f"1/{round(1 / speed)}x" if speed < 1 else f"{speed:g}x"


# ------------------------------------------------------------------------------- the viewer loop
REFERENCE_RGBA = (0.35, 0.65, 1.0, 0.5)


def draw_reference(scene: Any, positions: Any, radius: float = 0.045) -> int:
    """Replace the user geoms of ``scene`` (an ``MjvScene``) with spheres at ``positions`` (B, 3) (or none)."""
    import mujoco
    import numpy as np

    scene.ngeom = 0
    if positions is None:
        return 0
    eye = np.eye(3).reshape(-1)
    rgba = np.asarray(REFERENCE_RGBA, dtype=np.float32)
    for p in np.asarray(positions, dtype=np.float64).reshape(-1, 3):
        if scene.ngeom >= scene.maxgeom:
            break
        mujoco.mjv_initGeom(scene.geoms[scene.ngeom], int(mujoco.mjtGeom.mjGEOM_SPHERE), np.array([radius, 0.0, 0.0]), p, eye, rgba)
        scene.ngeom += 1
    return int(scene.ngeom)


def run_viewer(
    player: Player,
    viewer: Any,
    data: Any,
    *,
    clock: Callable[[], float] = time.perf_counter,
    sleep: Callable[[float], None] = time.sleep,
    on_status: Callable[[str], None] | None = None,
    max_frames: int | None = None,
) -> int:
    """The real-time loop: keys, :meth:`Player.advance` by the elapsed wall time, the simulator's env
    0 written into ``data`` with the reference as spheres, ``viewer.sync()``; until the viewer
    closes (or ``max_frames``). Returns the frames drawn."""
    last = clock()
    frames = 0
    shown = None
    while viewer.is_running():
        player.process_keys()
        now = clock()
        player.advance(now - last)
        last = now
        with viewer.lock():
            player.sim.write_mjdata(0, data)
            if getattr(viewer, "user_scn", None) is not None:
                draw_reference(viewer.user_scn, player.reference_positions())
        status = player.status()
        if status != shown:
            shown = status
            if on_status is not None:
                on_status(status)
        _set_text(viewer, f"{status} | t {player.steps * player.dt:.2f} s")
        viewer.sync()
        frames += 1
        if max_frames is not None and frames >= max_frames:
            break
        sleep(max(0.0, player.dt - (clock() - now)))
    return frames


def _set_text(viewer: Any, text: str) -> None:
    setter = getattr(viewer, "set_texts", None)
    if not callable(setter):
        return
    try:
        import mujoco

        setter((int(mujoco.mjtFontScale.mjFONTSCALE_150), int(mujoco.mjtGridPos.mjGRID_TOPLEFT), text, HELP))
    except Exception:  # noqa: BLE001 - an overlay is a nicety
        pass


def display_available(environ: Any = None, platform: str | None = None) -> tuple[bool, str]:
    """Whether an interactive window can be opened: ``(ok, why not)``."""
    env = os.environ if environ is None else environ
    platform = sys.platform if platform is None else platform
    if platform.startswith("linux") or "bsd" in platform:
        if not env.get("DISPLAY") and not env.get("WAYLAND_DISPLAY"):
            return False, "no display (DISPLAY and WAYLAND_DISPLAY are unset)"
    try:
        import mujoco.viewer  # noqa: F401
    except Exception as exc:  # noqa: BLE001 - glfw missing, no GL library
        return False, f"mujoco.viewer cannot be loaded ({type(exc).__name__}: {exc})"
    return True, ""


def _render_hint(target: Path, clip: str | None) -> str:
    return f"write a video instead: mocap render {target} --clip {clip or 'walk'} --out {clip or 'walk'}.mp4"


def play(
    target: Path,
    *,
    clip: str | None = None,
    generate: bool = False,
    speed: float = 1.0,
    noise: float = 1.0,
    seed: int = 0,
    horizon: float = 10.0,
    motions: str | None = None,
    imitator_only: bool = False,
    console: Any = None,
    environ: Any = None,
) -> int:
    """``mocap play``: the viewer on one env of ``target``'s simulator (module docstring). Returns the frames drawn."""
    from mocap.errors import UserError

    if not speed > 0:
        raise UserError(f"--speed must be positive, got {speed:g}")
    ok, why = display_available(environ)
    if not ok:
        raise UserError(f"mocap play needs a display: {why}; {_render_hint(target, clip)}")
    from mocap.eval_targets import build_evaluation_target, load_evaluation_target
    from mocap.plugins import get_plugins

    plugins = get_plugins()
    loaded = build_evaluation_target(load_evaluation_target(target, plugins), plugins, motions=motions, use_latent=not imitator_only)
    sim = loaded.make_sim(1)
    if not isinstance(sim, MujocoBacked):
        raise UserError(f"the {type(sim).__name__} simulator has no MuJoCo model to show; {_render_hint(target, clip)}")
    player = Player(loaded, sim, clip=clip, generate=generate, noise=noise, seed=seed, horizon=horizon)
    player.controls.speed_index = min(range(len(SPEEDS)), key=lambda i: abs(math.log(SPEEDS[i] / max(speed, 1e-6))))
    import mujoco
    import mujoco.viewer

    data = mujoco.MjData(sim.model)
    sim.write_mjdata(0, data)
    try:
        viewer = mujoco.viewer.launch_passive(sim.model, data, key_callback=player.key_callback, show_left_ui=False, show_right_ui=False)
    except Exception as exc:  # noqa: BLE001 - no GLFW window (macOS without mjpython, no GL)
        raise UserError(f"cannot open the MuJoCo viewer ({type(exc).__name__}: {exc}); {_render_hint(target, clip)}") from None
    say = (lambda s: console.print(s, highlight=False)) if console is not None else (lambda s: None)
    say(HELP)
    with viewer:
        with viewer.lock():
            viewer.cam.type = int(mujoco.mjtCamera.mjCAMERA_TRACKING)
            free = [j for j in range(sim.model.njnt) if int(sim.model.jnt_type[j]) == int(mujoco.mjtJoint.mjJNT_FREE)]
            viewer.cam.trackbodyid = int(sim.model.jnt_bodyid[free[0]]) if free else 1  # the humanoid's root
            viewer.cam.distance = 4.0
        frames = run_viewer(player, viewer, data, on_status=say)
    sim.close()
    return frames


# ------------------------------------------------------------------------------- headless video
def render_policy(
    target: Path,
    out: Path,
    *,
    clip: str | None = None,
    seconds: float | None = None,
    generate: bool = False,
    noise: float = 1.0,
    seed: int = 0,
    motions: str | None = None,
    imitator_only: bool = False,
    width: int = 640,
    height: int = 480,
) -> tuple[Path, str]:
    """``mocap render TARGET``: the rollout ``mocap play`` shows, written to ``out`` (.mp4 / .gif).

    Imitate (default): :func:`mocap.imitation_eval.record_video` of ``clip`` for ``seconds`` (default:
    the clip's duration; looping clips 10 s) with the reference as a ghost. ``generate``: a prior
    sample (:class:`Player` in generate mode, ``seed``) for ``seconds`` (default 10). Frames are
    ``width`` x ``height`` at the control rate. Returns the path and a one-line description."""
    from mocap.errors import UserError
    from mocap.eval_targets import build_evaluation_target, load_evaluation_target
    from mocap.imitation_eval import record_video
    from mocap.paths import check_output_file
    from mocap.plugins import get_plugins

    check_output_file(Path(out), "--out", video=True)
    if seconds is not None and not seconds > 0:
        raise UserError(f"--seconds must be positive, got {seconds:g}")
    from mocap.task_run import is_task_target
    from mocap.task_video import render_task

    if is_task_target(Path(target)) and clip is None and not generate and not imitator_only:
        # a run with a trained task stage (or its export): the task policy acting through its latent space
        return render_task(Path(target), Path(out), seconds=seconds or 10.0, seed=seed, width=width, height=height)
    plugins = get_plugins()
    loaded = build_evaluation_target(load_evaluation_target(target, plugins), plugins, motions=motions, use_latent=not imitator_only)
    lib = loaded.library

    def make_sim(n: int) -> Any:  # the simulator, its recorder sized to width x height
        sim = loaded.make_sim(n)
        base = sim.make_recorder
        sim.make_recorder = lambda **options: base(**{"width": width, "height": height, **options})  # type: ignore[method-assign]
        return sim

    if generate:
        sim = make_sim(1)
        player = Player(loaded, sim, clip=clip, generate=True, noise=noise, seed=seed, horizon=seconds or 10.0)
        recorder = sim.make_recorder()
        if recorder is None:
            raise UserError(f"the {type(sim).__name__} simulator cannot render videos")
        steps = max(1, int(round(player.horizon / player.dt)))
        for _ in range(steps):
            if player.controls.mode != "generate":  # the latent cannot act without a reference
                raise UserError(player.controls.message)
            player.step()
            recorder.add_frame(player.state)
        recorder.save(out)
        sim.close()
        return Path(out), f"prior sample (seed {seed}, noise {noise:g}), {steps} frames, {steps * player.dt:.2f} s"
    name = clip if clip is not None else lib.clip_names[0]
    try:
        c = lib.clip_index(name)
    except KeyError as exc:
        raise UserError(str(exc.args[0])) from None
    if seconds is None:
        seconds = 10.0 if bool(lib.loops[c]) else float(lib.durations[c])
    path = record_video(loaded.policy, lib, make_sim, name, seconds, Path(out))
    if path is None:
        raise UserError("the simulator cannot render videos")
    return path, f"clip {name}, {seconds:.2f} s, reference as a blue ghost"


__all__ = ["KEYS", "SPEEDS", "PlayControls", "Player", "display_available", "draw_reference", "play", "render_policy", "run_viewer"]
