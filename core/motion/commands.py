"""``mocap motions``: list and inspect the clips a motion source provides.

``mocap motions list [--source deepmimic] [--path P ...] [--clip NAME ...] [--humanoid H] [--json]``
prints name, frames, fps, duration and looping for every clip (files that could not be loaded are
listed as warnings on stderr); ``mocap motions show NAME`` prints one clip's details. Sources and
humanoids are looked up in the plugin registry, so third-party motion sources work too: ``--path``
fills the source's ``paths`` parameter and ``--clip`` its ``clips`` parameter. Bad input (unknown
source or clip, unreadable files, invalid parameters) is one message on stderr and exit code 2.
"""

from __future__ import annotations

import difflib
import json
import sys
from dataclasses import asdict
from pathlib import Path
from typing import Annotated, Any, Optional

import typer
from pydantic import ValidationError
from rich.console import Console
from rich.table import Table

from mocap.motion.clip import MotionDataError

EXIT_USER_ERROR = 2

motions_app = typer.Typer(
    name="motions",
    help="List and inspect motion clips (DeepMimic bundled clips, AMASS, native .npz).",
    no_args_is_help=True,
    add_completion=False,
)

SourceOpt = Annotated[str, typer.Option("--source", help="registered motion source (deepmimic, amass, npz, ...)")]
PathOpt = Annotated[Optional[list[Path]], typer.Option("--path", "-p", help="file or folder for the source's 'paths' (repeatable)", show_default=False)]
ClipOpt = Annotated[Optional[list[str]], typer.Option("--clip", "-c", help="clip name for the source's 'clips' (repeatable)", show_default=False)]
HumanoidOpt = Annotated[Optional[str], typer.Option("--humanoid", help="humanoid to load onto (default: the source's own, e.g. amp for deepmimic)")]
JsonOpt = Annotated[bool, typer.Option("--json", help="machine-readable output")]


def _fail(message: str) -> typer.Exit:
    Console(stderr=True, soft_wrap=True).print(f"[red]error:[/] {message}", highlight=False)
    return typer.Exit(EXIT_USER_ERROR)


def _validation_message(exc: ValidationError) -> str:
    parts = []
    for err in exc.errors():
        loc = ".".join(str(x) for x in err.get("loc", ())) or "params"
        parts.append(f"{loc}: {err.get('msg', '')}")
    return "; ".join(parts)


def load_motion_set(source: str, paths: list[Path] | None, clips: list[str] | None, humanoid: str | None) -> tuple[Any, str]:
    """Build ``source`` from the registry with ``paths``/``clips``, load it; return (MotionSet, humanoid).

    Every user error is turned into :class:`typer.Exit` (code 2) after one message on stderr.
    """
    from mocap.plugins import PluginError, get_plugins

    try:
        pset = get_plugins()
        comp = pset.get("motion_source", source)
        raw: dict[str, Any] = {}
        if paths:
            raw["paths"] = [str(p) for p in paths]
        if clips:
            raw["clips"] = list(clips)
        src = comp.build(raw)
        name = humanoid or getattr(src, "default_humanoid", None) or "amp"
        skeleton = pset.get("humanoid", name).build({})
        return src.load(skeleton), name
    except ValidationError as exc:
        raise _fail(f"motion source {source!r}: {_validation_message(exc)}") from None
    except (PluginError, MotionDataError, KeyError, ValueError) as exc:
        message = exc.args[0] if isinstance(exc, KeyError) and exc.args else str(exc)
        raise _fail(str(message)) from None


def _warn_skipped(mset: Any) -> None:
    err = Console(stderr=True, soft_wrap=True)
    for _path, reason in mset.skipped:
        err.print(f"[yellow]skipped:[/] {reason}", highlight=False)


@motions_app.command("list")
def cmd_list(
    source: SourceOpt = "deepmimic",
    path: PathOpt = None,
    clip: ClipOpt = None,
    humanoid: HumanoidOpt = None,
    as_json: JsonOpt = False,
) -> None:
    """List the clips of a motion source: name, frames, fps, duration, looping."""
    from mocap.motion.library import ClipInfo

    mset, hname = load_motion_set(source, path, clip, humanoid)
    infos = [ClipInfo.of(c) for c in mset.clips]
    if as_json:
        data = {
            "source": source,
            "humanoid": hname,
            "clips": [asdict(i) for i in infos],
            "skipped": [{"path": p, "reason": r} for p, r in mset.skipped],
        }
        sys.stdout.write(json.dumps(data, indent=2) + "\n")
        return
    table = Table(title=f"{source} motions on {hname} ({len(infos)} clips)")
    for col, justify in (("name", "left"), ("frames", "right"), ("fps", "right"), ("duration s", "right"), ("looping", "center")):
        table.add_column(col, justify=justify)  # type: ignore[arg-type]
    for i in infos:
        table.add_row(i.name, str(i.num_frames), f"{i.fps:g}", f"{i.duration:.3f}", "yes" if i.loop else "no")
    Console(soft_wrap=True).print(table)
    _warn_skipped(mset)


@motions_app.command("show")
def cmd_show(
    name: Annotated[str, typer.Argument(help="clip name (as `mocap motions list` prints it)")],
    source: SourceOpt = "deepmimic",
    path: PathOpt = None,
    humanoid: HumanoidOpt = None,
    as_json: JsonOpt = False,
) -> None:
    """Details of one clip: frames, fps, duration, loop, root height range, distance travelled, source file."""
    from mocap.motion.library import ClipInfo

    mset, hname = load_motion_set(source, path, None, humanoid)
    by_name = {c.name: c for c in mset.clips}
    if name not in by_name:
        close = difflib.get_close_matches(name, list(by_name), n=3)
        hint = f"did you mean {', '.join(close)}?" if close else f"clips: {', '.join(by_name)}"
        raise _fail(f"no clip {name!r} in motion source {source!r}; {hint}")
    info = ClipInfo.of(by_name[name])
    if as_json:
        sys.stdout.write(json.dumps(asdict(info), indent=2) + "\n")
        return
    table = Table(title=f"{info.name} ({source}, {hname})", show_header=False)
    table.add_column("field", no_wrap=True)
    table.add_column("value", overflow="fold")
    rows = [
        ("frames", str(info.num_frames)),
        ("fps", f"{info.fps:g}"),
        ("duration", f"{info.duration:.3f} s"),
        ("loop", "wrap (last frame = next cycle's first)" if info.loop else "none (clamps at the end)"),
        ("root height", f"{info.root_height_min:.3f} .. {info.root_height_max:.3f} m"),
        ("distance travelled", f"{info.distance:.3f} m (horizontal root path)"),
        ("displacement", f"{info.displacement:.3f} m (first to last frame" + (", per cycle)" if info.loop else ")")),
        ("skeleton", info.skeleton),
        ("source", info.source),
    ]
    for k, v in rows:
        table.add_row(k, v)
    Console(soft_wrap=True).print(table)
