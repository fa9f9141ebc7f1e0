"""Progress of an iterative trainer: a live rich bar on a terminal, a plain line otherwise."""

from __future__ import annotations

from typing import Any, Sequence


class IterationProgress:
    """Shows ``label: it N | steps | steps/s | <fields>`` for each iteration.

    On a terminal it is a rich progress bar with time remaining; elsewhere (logs, CI) a plain line
    every ``every`` iterations. ``fields`` are ``(stats key, short name, format)`` shown when present.
    """

    def __init__(self, console: Any, total: int, every: int, label: str, fields: Sequence[tuple[str, str, str]]):
        self.console = console
        self.total = total
        self.every = every
        self.label = label
        self.fields = tuple(fields)
        self.bar: Any = None
        self.task: Any = None
        if console is not None and getattr(console, "is_terminal", False):
            from rich.progress import BarColumn, MofNCompleteColumn, Progress, TextColumn, TimeRemainingColumn

            self.bar = Progress(
                TextColumn(f"[bold]{label}[/]"),
                BarColumn(),
                MofNCompleteColumn(),
                TimeRemainingColumn(),
                TextColumn("{task.description}"),
                console=console,
            )
            self.task = self.bar.add_task("", total=total)
            self.bar.start()

    def line(self, iteration: int, env_steps: int, stats: dict[str, float]) -> str:
        parts = [f"it {iteration}", f"{env_steps:,} steps", f"{stats.get('steps_per_s', 0.0):,.0f} steps/s"]
        parts += [f"{name} {format(stats[key], fmt)}" for key, name, fmt in self.fields if key in stats]
        return " | ".join(parts)

    def update(self, iteration: int, env_steps: int, stats: dict[str, float]) -> None:
        text = self.line(iteration, env_steps, stats)
        if self.bar is not None:
            self.bar.update(self.task, completed=iteration, description=text)
        elif self.console is not None and (iteration % self.every == 0 or iteration == self.total):
            self.console.print(f"{self.label}: {text}")

    def close(self) -> None:
        if self.bar is not None:
            self.bar.stop()
            self.bar = None
