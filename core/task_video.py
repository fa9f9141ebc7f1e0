"""A trained task policy on video: ``mocap render RUN_DIR`` for a run with a ``task`` stage.

:func:`render_task` reopens the task stage with one env (:func:`mocap.task_run.open_task_run`: the
run directory's spec, frozen latent space and task policy), rolls the task policy out with its
deterministic action, and records env 0 with the simulator's video recorder. Episodes restart as in
training (on termination or at the episode length), so a fall is visible and followed by a reset.

Goals are drawn as marker spheres when the task exposes ``markers(env_id) -> [(pos, rgba,
radius), ...]`` (reach: the hand target; speed: a point 1 m ahead of the root in the target
direction; strike: the target's centre and top, so a knocked-over target shows).
"""

from __future__ import annotations

from pathlib import Path

from mocap.errors import UserError
from mocap.task_run import open_task_run, task_stage


def render_task(run_dir: Path, out: Path, *, seconds: float = 10.0, seed: int | None = None, width: int = 640, height: int = 480) -> tuple[Path, str]:
    """Record the task policy of ``run_dir`` for ``seconds`` into ``out`` (module docstring)."""
    run = open_task_run(Path(run_dir), 1, seed)
    env = run.env
    try:
        recorder = env.sim.make_recorder(width=width, height=height)
        if recorder is None:
            raise UserError(f"the {type(env.sim).__name__} simulator cannot render videos")
        obs = env.reset()
        steps = max(1, int(round(seconds / float(env.sim.dt))))
        episodes = falls = 0
        for _ in range(steps):
            result = env.step(run.act(obs))
            obs = result.obs
            recorder.add_frame(env.sim.state, markers=env.task.markers(0))
            if bool(result.terminated[0] | result.truncated[0]):
                episodes += 1
                falls += int(result.terminated[0])
        recorder.save(out)
    finally:
        run.close()
    return Path(out), f"{run.label}, {steps} frames, {steps * float(env.sim.dt):.2f} s, {episodes} episode end(s) of which {falls} terminated"


__all__ = ["render_task", "task_stage"]
