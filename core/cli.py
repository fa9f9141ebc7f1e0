"""The ``mocap`` command line (typer). Plugins add commands through ``register_commands(app)``.

Exit codes: 0 success, 1 a run failed, 2 bad user input (spec, plugin names, data files, checkpoints,
an unwritable --out, a full disk, a missing package),
130 interrupted (the run saved a checkpoint; the same command resumes it).
"""

from __future__ import annotations

import json
import sys
from pathlib import Path
from typing import Annotated, Optional

import typer
from rich.console import Console
from rich.table import Table

from mocap import __version__
from mocap.plugins import PluginSet, get_plugins

console = Console(soft_wrap=True)
err_console = Console(stderr=True, soft_wrap=True)

EXIT_USER_ERROR = 2
EXIT_INTERRUPTED = 130


from mocap.errors import UserError, user_errors  # noqa: E402  (re-exported: mocap.cli.UserError)
from mocap.paths import check_output_dir, check_output_file  # noqa: E402  (re-exported)


#: third-party modules -> the pip package that provides them (for the "not installed" message)
PIP_NAMES = {"pybullet_data": "pybullet", "cv2": "opencv-python", "yaml": "pyyaml", "PIL": "pillow", "sklearn": "scikit-learn"}


def missing_package_message(exc: ImportError) -> str | None:
    """One line for a third-party package that is missing or broken (an incomplete install), or
    None when the failed import is mocap's own (a bug: keep the traceback)."""
    name = getattr(exc, "name", None)
    if not name:
        return None
    top = name.split(".")[0]
    if top == "mocap" or top.startswith("mocap_"):
        return None
    package = PIP_NAMES.get(top, top)
    extra = "; it provides the DeepMimic clips and the amp humanoid's URDF" if package == "pybullet" else ""
    return f"the Python package {package!r} is missing or broken (importing {name!r} failed{extra}); install it into this environment: pip install {package}"


#: longest error line printed (a 10 MB string from a checkpoint must not reach the terminal whole)
MAX_ERROR_CHARS = 2000


def capped(message: str, limit: int = MAX_ERROR_CHARS) -> str:
    """``message`` cut to ``limit`` characters, saying how much was left out."""
    if len(message) <= limit:
        return message
    return f"{message[:limit]} ... [{len(message) - limit:,} more characters]"


def fail(message: str, code: int = EXIT_USER_ERROR) -> "typer.Exit":
    err_console.print(f"[red]error:[/] {capped(message)}", highlight=False)
    return typer.Exit(code)


def report_plugin_failures(pset: PluginSet) -> None:
    for failure in pset.failures:
        err_console.print(f"[yellow]warning:[/] {failure.line()}", highlight=False)


def _plugins() -> PluginSet:
    return get_plugins()


SetOption = Annotated[
    Optional[list[str]],
    typer.Option("--set", "-s", help="override a spec field: a.b.c=value (repeatable)", show_default=False),
]


def _load(spec_path: Path, overrides: list[str] | None):  # -> ResolvedSpec
    from mocap.spec import load_spec

    pset = _plugins()
    return load_spec(spec_path, pset, overrides or [])


def cmd_validate(spec: Annotated[Path, typer.Argument(help="spec YAML file")], set_: SetOption = None) -> None:
    """Check a spec (structure, plugin names, every component's params) without running it."""
    from mocap.matrix import load_cells
    from mocap.stage_keys import resolved_stage_keys

    cells = load_cells(spec, _plugins(), set_ or [])
    for cell, resolved in cells:
        keys = resolved_stage_keys(resolved, _plugins())
        stages = ", ".join(f"{s} ({k})" for s, k in keys.items()) or "none"
        what = f"cell {cell.name} of {spec}" if cell.name else str(spec)
        console.print(f"[green]ok[/]: {what} is a valid spec {resolved.spec.name!r}; stages: {stages}", highlight=False)


def cmd_run(
    spec: Annotated[Path, typer.Argument(help="spec YAML file")],
    set_: SetOption = None,
    out: Annotated[Optional[Path], typer.Option("--out", "-o", help="run directory (default: runs/<spec name>)")] = None,
    store: Annotated[Optional[Path], typer.Option("--store", help="artifact store shared between runs (default: <run dir>/../artifacts)")] = None,
    jobs: Annotated[int, typer.Option("--jobs", "-j", min=1, help="comparison specs: cells run at the same time (processes)")] = 1,
    executor: Annotated[
        str,
        typer.Option(
            "--executor",
            help="comparison specs: where cells run: 'local' (this process, or --jobs local processes) or "
            "'ray' (Ray tasks, at most --jobs at a time; pip install 'mocap\\[ray]')",
        ),
    ] = "local",
    ray_address: Annotated[
        Optional[str],
        typer.Option(
            "--ray-address",
            help="with --executor ray: the cluster to join ('auto': the one running on this machine, or an address); "
            "default: start a local Ray instance. Several nodes need the run directory on a shared filesystem",
            show_default=False,
        ),
    ] = None,
    ray_cpus_per_cell: Annotated[float, typer.Option("--ray-cpus-per-cell", min=0.01, help="with --executor ray: CPUs Ray reserves for each cell")] = 1.0,
) -> None:
    """Run a spec: imitator -> latent -> task -> eval, reusing artifacts of identical stages.

    A spec with a ``matrix:`` runs one cell per combination of its values (see mocap.matrix) and
    writes a comparison table."""
    from mocap.matrix import EXECUTORS, ExecutorError, comparison, import_ray, load_cells, run_cells
    from mocap.pipeline import PipelineInterrupted, run_pipeline

    if executor not in EXECUTORS:
        raise fail(f"--executor {executor}: choose one of {', '.join(EXECUTORS)}")
    if executor != "ray" and (ray_address is not None or ray_cpus_per_cell != 1.0):
        raise fail("--ray-address and --ray-cpus-per-cell need --executor ray")
    cells = load_cells(spec, _plugins(), set_ or [])
    if store is not None:
        check_output_dir(store, "--store")
    if len(cells) > 1 or cells[0][0].name:
        out_dir = out or Path("runs") / cells[0][1].spec.name
        check_output_dir(out_dir)
        try:
            if executor == "ray":
                import_ray()  # before anything runs
            console.print(f"comparison: {len(cells)} cells -> {out_dir}/<cell>/", highlight=False)
            status = run_cells(
                cells,
                _plugins(),
                out_dir,
                console,
                jobs=jobs,
                store=store,
                executor=executor,
                ray_address=ray_address,
                cpus_per_cell=ray_cpus_per_cell,
            )
        except ExecutorError as exc:
            from rich.markup import escape

            raise fail(escape(str(exc))) from None  # escaped: rich would eat the "[ray]" of "mocap[ray]"
        except PipelineInterrupted as exc:
            err_console.print(f"[yellow]interrupted[/] during stage {exc.args[0]!r}; run the same command again to resume.")
            raise typer.Exit(EXIT_INTERRUPTED) from None
        data = comparison([c for c, _ in cells], out_dir)
        from mocap.matrix import render as render_comparison

        console.print(render_comparison(data["groups"]), highlight=False, markup=False)
        failed = [name for name, s in status.items() if s != "done"]
        console.print(f"[bold green]done[/]: {len(cells) - len(failed)}/{len(cells)} cells; comparison: {out_dir / 'comparison.md'}", highlight=False)
        console.print(
            f"next: each cell's report is {out_dir}/<cell>/report.md; `mocap eval {out_dir}/<cell>` prints its per-clip table; more specs to run are in specs/",
            highlight=False,
        )
        if failed:
            raise typer.Exit(EXIT_USER_ERROR)
        return
    resolved = cells[0][1]
    if executor == "ray":
        console.print("note: --executor ray runs the cells of comparison specs; this spec has no matrix and runs here", highlight=False)
    out_dir = out or Path("runs") / resolved.spec.name
    check_output_dir(out_dir)
    if store is None:
        from mocap.pipeline import artifact_store

        check_output_dir(artifact_store(out_dir), "--store (default: next to --out)")
    try:
        records = run_pipeline(resolved, _plugins(), out_dir, store=store, console=console)
    except PipelineInterrupted as exc:
        err_console.print(f"[yellow]interrupted[/] during stage {exc.args[0]!r}; its checkpoint is saved. Run the same command again to resume.")
        raise typer.Exit(EXIT_INTERRUPTED) from None
    console.print(f"[bold green]done[/]: {len(records)} stage(s); report: {out_dir / 'report.md'}", highlight=False)
    from mocap.report import headline

    for line in headline(records):
        console.print(f"  {line}", highlight=False)
    if resolved.spec.task is not None:  # a task policy: its own evaluation, not the imitation protocol
        console.print(
            f"next: `mocap task-eval {out_dir}` evaluates the task policy (task error in units, falls); "
            f"`mocap render {out_dir} --out task.mp4` shows it; more specs to run are in specs/",
            highlight=False,
        )
    elif resolved.spec.imitator is not None:
        console.print(f"next: `mocap eval {out_dir}` prints the per-clip imitation table; more specs to run are in specs/", highlight=False)


def cmd_schema(
    out: Annotated[Optional[Path], typer.Option("--out", "-o", help="write to this file instead of stdout")] = None,
) -> None:
    """Print the JSON Schema of specs (component params typed by the installed plugins)."""
    from mocap.spec import json_schema

    text = json.dumps(json_schema(_plugins()), indent=2)
    if out is None:
        sys.stdout.write(text + "\n")
    else:
        write_user_file(out, text + "\n", "--out")
        console.print(f"wrote {out}")


def write_user_file(path: Path, text: str, option: str) -> None:
    """Write ``text`` to a file the user named: :func:`mocap.paths.write_output_text` (a path that
    cannot be written is a :class:`UserError` naming it, not a traceback)."""
    from mocap.paths import write_output_text

    write_output_text(path, text, option)


def cmd_plugins(as_json: Annotated[bool, typer.Option("--json", help="machine-readable output")] = False) -> None:
    """List installed plugins: name, package, version, hooks, and what they register."""
    pset = _plugins()
    registered: dict[str, list[str]] = {}
    for kind, comps in pset.components.items():
        for name, comp in sorted(comps.items()):
            registered.setdefault(comp.plugin, []).append(f"{kind}:{name}")
    duplicates = [{"kind": k, "name": n, "plugins": owners} for (k, n), owners in sorted(pset.duplicates.items())]
    if as_json:
        data = {
            "plugins": [
                {
                    "name": p.name,
                    "package": p.package,
                    "version": p.version,
                    "module": p.module,
                    "hooks": list(p.hooks),
                    "registers": registered.get(p.name, []),
                }
                for p in pset.plugins
            ],
            "failures": [{"name": f.name, "package": f.package, "error": f.error} for f in pset.failures],
            "duplicates": duplicates,
        }
        sys.stdout.write(json.dumps(data, indent=2) + "\n")
    else:
        table = Table(title=f"mocap {__version__} plugins")
        for col in ("name", "package", "version", "hooks", "registers"):
            table.add_column(col)
        for p in pset.plugins:
            table.add_row(p.name, p.package, p.version, "\n".join(p.hooks), "\n".join(registered.get(p.name, [])))
        # piped (not a terminal): no 80-column limit, so names are never cut ("trainer:imitati…")
        (console if console.is_terminal else Console(width=1000, soft_wrap=True)).print(table)
    for dup in duplicates:
        err_console.print(
            f"[red]error:[/] {dup['kind']} {dup['name']!r} is registered by more than one plugin: {' and '.join(repr(o) for o in dup['plugins'])}",
            highlight=False,
        )
    if duplicates:
        raise typer.Exit(EXIT_USER_ERROR)


def cmd_checkpoint_convert(
    path: Annotated[Path, typer.Argument(help="an older mocap checkpoint (.pt) that a safe load refuses")],
    out: Annotated[Optional[Path], typer.Option("--out", "-o", help="write here (default: replace the file)")] = None,
    trust: Annotated[bool, typer.Option("--trust", help="confirm that you trust the file: converting runs its pickled code")] = False,
) -> None:
    """Rewrite an older checkpoint into the safe form that mocap loads without running code.

    Converting unpickles the file without restriction, i.e. runs any code it holds: only for files
    you trust (yours, or an official release). Needs --trust."""
    from mocap.checkpoint import atomic_write_bytes, convert_checkpoint, loads_safely

    if path.is_file() and loads_safely(path):  # before --trust: nothing would be unpickled
        copied = ""
        if out is not None and out.resolve() != path.resolve():
            check_output_file(out, "--out")
            atomic_write_bytes(out, path.read_bytes())
            copied = f"; copied unchanged to {out}"
        console.print(f"{path} already loads without running code: nothing to convert, the file is left as it is{copied}", highlight=False)
        return
    if not trust:
        raise UserError(f"{path}: converting a checkpoint runs any code pickled in it; only convert files you trust, and say so with --trust")
    err_console.print(f"[yellow]warning:[/] unpickling {path} without restriction (trusted by --trust)", highlight=False)
    dst = convert_checkpoint(path, out)
    console.print(f"wrote {dst} (loads without running code)", highlight=False)


def cmd_switches(
    out: Annotated[Optional[Path], typer.Option("--out", "-o", help="write to this file instead of stdout")] = None,
    all_packages: Annotated[bool, typer.Option("--all", help="also third-party plugins' components")] = False,
) -> None:
    """Print every paper / official-code switch of the installed components and its default (Markdown)."""
    from mocap.switches import render

    text = render(_plugins(), None if all_packages else {"mocap"})
    if out is None:
        sys.stdout.write(text)
    else:
        write_user_file(out, text, "--out")
        console.print(f"wrote {out}")


def build_app(pset: PluginSet | None = None) -> typer.Typer:
    """The root app with the core commands and every plugin's commands."""
    app = typer.Typer(
        name="mocap",
        help="Physics-based humanoid motion representations: run, validate and inspect specs.",
        no_args_is_help=True,
        pretty_exceptions_show_locals=False,
        add_completion=False,
        context_settings={"help_option_names": ["-h", "--help"]},  # every subcommand inherits it
    )
    app.command("run")(cmd_run)
    app.command("validate")(cmd_validate)
    app.command("schema")(cmd_schema)
    app.command("plugins")(cmd_plugins)
    app.command("switches")(cmd_switches)
    checkpoint_app = typer.Typer(name="checkpoint", help="Checkpoint files: convert older ones to the safe format.", no_args_is_help=True)
    checkpoint_app.command("convert")(cmd_checkpoint_convert)
    app.add_typer(checkpoint_app)

    @app.callback(invoke_without_command=True)
    def _root(
        version: Annotated[bool, typer.Option("--version", help="print the version and exit")] = False,
    ) -> None:
        if version:
            console.print(f"mocap {__version__}")
            raise typer.Exit(0)

    (pset or _plugins()).commands(app)
    return app


def main(argv: list[str] | None = None) -> int:
    """Console-script entry point: user errors are one clear message and exit code 2."""
    pset = _plugins()
    app = build_app(pset)
    report_plugin_failures(pset)
    try:
        rc = app(args=argv, standalone_mode=False, prog_name="mocap")
        return rc if isinstance(rc, int) else 0
    except typer.Exit as exc:
        return int(exc.exit_code or 0)
    except user_errors() as exc:
        message = exc.format() if hasattr(exc, "format") and callable(exc.format) else str(exc)
        err_console.print(f"[red]error:[/] {capped(message)}", highlight=False)
        return EXIT_USER_ERROR
    except KeyboardInterrupt:
        err_console.print("[yellow]interrupted[/]")
        return EXIT_INTERRUPTED
    except ImportError as exc:  # a third-party package missing or half-installed: the environment, not a bug
        message = missing_package_message(exc)
        if message is None:
            raise
        err_console.print(f"[red]error:[/] {message}", highlight=False)
        return EXIT_USER_ERROR
    except Exception as exc:  # usage errors of typer's (vendored) click arrive here in non-standalone mode
        show, exit_code = getattr(exc, "show", None), getattr(exc, "exit_code", None)
        if callable(show) and isinstance(exit_code, int):
            show()
            return exit_code
        if type(exc).__name__ == "Abort":
            err_console.print("[yellow]aborted[/]")
            return EXIT_INTERRUPTED
        raise
    return 0


if __name__ == "__main__":  # `python -m mocap.cli ...` (used by `mocap run --jobs`)
    sys.exit(main())
