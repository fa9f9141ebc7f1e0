"""``mocap render``: kinematic playback of a motion clip, or a policy's rollout, into an MP4 or GIF (offscreen MuJoCo).

Policy mode: ``mocap render TARGET [--clip C | --generate] [--seconds S] [--out F]`` writes the
rollout ``mocap play TARGET`` shows (:func:`mocap.play.render_policy`). Kinematic mode:

``mocap render --motion NAME [--source deepmimic] [--path P ...] [--humanoid amp] [--out NAME.mp4]
[--seconds S] [--fps 30] [--width 640] [--height 480]`` loads the clip from a registered motion
source, samples it with the :class:`~mocap.motion.library.MotionLibrary` every ``1/fps`` s from 0 to
``seconds`` (default: the clip's duration; looping clips continue past it, moving on by one cycle
offset per cycle) and renders each pose with :class:`~mocap_sim_mujoco.render.VideoRecorder`
(tracking camera, checkered floor). Bad input (unknown motion, source or humanoid, bad sizes, an
unsupported file type) and a missing OpenGL backend are one message on stderr and exit code 2.
"""

from __future__ import annotations

import difflib
from pathlib import Path
from typing import Annotated, Any, Optional

import typer
from rich.console import Console
from rich.progress import BarColumn, MofNCompleteColumn, Progress, TextColumn, TimeRemainingColumn

from mocap.hooks import hookimpl

EXIT_USER_ERROR = 2
MAX_VIDEO_BYTES = 4 * 2**30  # frames are kept in memory until the video is written


def _fail(message: str) -> typer.Exit:
    Console(stderr=True, soft_wrap=True).print(f"[red]error:[/] {message}", highlight=False)
    return typer.Exit(EXIT_USER_ERROR)


def cmd_render(
    target: Annotated[
        Optional[Path],
        typer.Argument(
            help="policy mode: a checkpoint (policy.pt, latent.pt), checkpoint directory, run directory or spec, rolled out as `mocap play` shows it",
            show_default=False,
        ),
    ] = None,
    motion: Annotated[Optional[str], typer.Option("--motion", "-m", help="kinematic mode: clip name (as `mocap motions list` prints it)")] = None,
    clip: Annotated[Optional[str], typer.Option("--clip", help="policy mode: the clip to imitate (default: the first)")] = None,
    generate: Annotated[bool, typer.Option("--generate", help="policy mode: random motion from the latent prior instead")] = False,
    noise: Annotated[float, typer.Option("--noise", help="policy mode, --generate: prior noise scale")] = 1.0,
    seed: Annotated[int, typer.Option("--seed", help="policy mode, --generate: seed of the start state and prior noise")] = 0,
    imitator_only: Annotated[
        bool, typer.Option("--imitator-only", help="policy mode: for a latent space, roll out the imitator it was distilled from")
    ] = False,
    source: Annotated[str, typer.Option("--source", help="registered motion source (deepmimic, amass, npz, ...)")] = "deepmimic",
    path: Annotated[Optional[list[Path]], typer.Option("--path", "-p", help="file or folder for the source's 'paths' (repeatable)", show_default=False)] = None,
    humanoid: Annotated[Optional[str], typer.Option("--humanoid", help="humanoid to load onto (default: the source's own, e.g. amp for deepmimic)")] = None,
    out: Annotated[Optional[Path], typer.Option("--out", "-o", help="output .mp4 or .gif (default: <motion>.mp4)")] = None,
    seconds: Annotated[Optional[float], typer.Option("--seconds", help="length of the video, s (default: the clip's duration)")] = None,
    fps: Annotated[float, typer.Option("--fps", help="frame rate of the video, Hz")] = 30.0,
    width: Annotated[int, typer.Option("--width", help="frame width, pixels")] = 640,
    height: Annotated[int, typer.Option("--height", help="frame height, pixels")] = 480,
) -> None:
    """Render a motion clip (--motion: kinematic playback) or a policy's rollout (TARGET) to an MP4 or GIF video."""
    from mocap.motion.commands import load_motion_set
    from mocap.paths import check_output_file

    if target is not None and motion is not None:
        raise _fail("give a TARGET (a policy's rollout) or --motion (kinematic playback), not both")
    if target is None and motion is None:
        raise _fail("nothing to render: give a TARGET (policy.pt, latent.pt, checkpoint/run directory, spec) or --motion NAME")
    if target is None and (clip is not None or generate):
        raise _fail("--clip and --generate need a TARGET policy; kinematic playback takes --motion")
    out_path = out if out is not None else Path(f"{motion or ('generate' if generate else clip or 'rollout')}.mp4")
    check_output_file(out_path, "--out", video=True)  # a .mp4 / .gif in a folder that exists, before any work
    if not fps > 0 or fps > 1000:
        raise _fail(f"--fps must be in (0, 1000], got {fps:g}")
    if not (16 <= width <= 8192 and 16 <= height <= 8192):
        raise _fail(f"--width/--height must be 16..8192 pixels, got {width}x{height}")
    if seconds is not None and not seconds > 0:
        raise _fail(f"--seconds must be positive, got {seconds:g}")
    if target is not None:
        _render_policy(target, out_path, clip, seconds, generate, noise, seed, imitator_only, width, height)
        return

    assert motion is not None  # target is None here, and one of the two was given (checked above)
    mset, hname = load_motion_set(source, path, None, humanoid)
    names = [c.name for c in mset.clips]
    if motion not in names:
        close = difflib.get_close_matches(motion, names, n=3)
        hint = f" (did you mean {', '.join(close)}?)" if close else ""
        raise _fail(f"no motion {motion!r} in source {source!r}{hint}; available: {', '.join(names) or '(none)'}")

    frames, skeleton, n = _sample(mset.clips[names.index(motion)], hname, seconds, fps)
    if n * width * height * 3 > MAX_VIDEO_BYTES:
        raise _fail(
            f"{n} frames of {width}x{height} need {n * width * height * 3 / 2**30:.1f} GiB in memory "
            f"(limit {MAX_VIDEO_BYTES / 2**30:.0f} GiB): lower --seconds, --fps or the frame size"
        )

    from mocap.errors import UserError

    try:  # importing the module can already fail: mujoco loads the MUJOCO_GL backend on import
        from mocap_sim_mujoco.render import VideoRecorder

        recorder = VideoRecorder(skeleton, width=width, height=height, fps=fps)
    except UserError as exc:  # RenderUnavailable
        raise _fail(str(exc)) from None
    err = Console(stderr=True)
    with (
        recorder,
        Progress(
            TextColumn("rendering {task.description}"),
            BarColumn(),
            MofNCompleteColumn(),
            TimeRemainingColumn(),
            console=err,
            transient=True,
        ) as progress,
    ):
        task = progress.add_task(motion, total=n)
        for i in range(n):
            recorder.add_frame(frames.root_pos[i], frames.root_rot[i], frames.dof_pos[i])
            progress.advance(task)
        try:
            written = recorder.save(out_path)
        except OSError as exc:
            raise _fail(f"cannot write {out_path}: {exc}") from None
    Console(soft_wrap=True).print(f"wrote {written} ({n} frames, {width}x{height}, {fps:g} fps, {n / fps:.2f} s)", highlight=False)


def _render_policy(
    target: Path,
    out: Path,
    clip: str | None,
    seconds: float | None,
    generate: bool,
    noise: float,
    seed: int,
    imitator_only: bool,
    width: int,
    height: int,
) -> None:
    """Policy mode: :func:`mocap.play.render_policy`, the rollout ``mocap play`` shows (frames at the
    simulator's control rate; ``--fps`` is for kinematic playback)."""
    from mocap.play import render_policy

    with Console(stderr=True).status(f"rendering {target}"):
        written, what = render_policy(
            target,
            out,
            clip=clip,
            seconds=seconds,
            generate=generate,
            noise=noise,
            seed=seed,
            imitator_only=imitator_only,
            width=width,
            height=height,
        )
    Console(soft_wrap=True).print(f"wrote {written} ({what}, {width}x{height})", highlight=False)


def _sample(clip: Any, humanoid: str, seconds: float | None, fps: float) -> tuple[Any, Any, int]:
    """MotionFrames of ``clip`` every ``1/fps`` s over ``[0, seconds]``, its skeleton, the frame count."""
    import torch

    from mocap.motion.library import MotionLibrary
    from mocap.plugins import get_plugins

    skeleton = get_plugins().get("humanoid", humanoid).build({})
    lib = MotionLibrary([clip], skeleton, dtype=torch.float64)
    length = float(lib.durations[0]) if seconds is None else float(seconds)
    n = max(1, int(length * fps + 1e-6) + 1)
    times = torch.arange(n, dtype=torch.float64) / fps
    return lib.frames(torch.zeros(n, dtype=torch.long), times), skeleton, n


def cmd_play(
    target: Annotated[Path, typer.Argument(help="a checkpoint (policy.pt, latent.pt), a checkpoint directory (checkpoints/<name>), a run directory or a spec")],
    clip: Annotated[Optional[str], typer.Option("--clip", help="clip to start with (default: the first)")] = None,
    generate: Annotated[bool, typer.Option("--generate", help="start with random motion from the latent prior")] = False,
    speed: Annotated[float, typer.Option("--speed", help="playback speed (slow motion < 1), nearest of 1/16 .. 4")] = 1.0,
    noise: Annotated[float, typer.Option("--noise", help="prior noise scale for G / --generate")] = 1.0,
    seed: Annotated[int, typer.Option("--seed", help="seed of the prior samples")] = 0,
    horizon: Annotated[float, typer.Option("--horizon", help="seconds per episode for looping clips and prior samples")] = 10.0,
    motions: Annotated[Optional[str], typer.Option("--motions", help="play clips of this motion source instead (default params)")] = None,
    imitator_only: Annotated[bool, typer.Option("--imitator-only", help="for a latent space: play the imitator it was distilled from")] = False,
) -> None:
    """Watch a policy imitate clips (or sample its latent prior) in MuJoCo's interactive viewer."""
    from mocap.play import play

    play(
        target,
        clip=clip,
        generate=generate,
        speed=speed,
        noise=noise,
        seed=seed,
        horizon=horizon,
        motions=motions,
        imitator_only=imitator_only,
        console=Console(stderr=True),
    )


@hookimpl
def register_commands(app: Any) -> None:
    app.command("render")(cmd_render)
    app.command("play")(cmd_play)
