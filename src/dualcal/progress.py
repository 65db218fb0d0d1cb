"""Progress bars on stderr (stdout stays free for data)."""

from __future__ import annotations

import contextlib
from collections.abc import Iterable, Iterator

from rich.console import Console
from rich.markup import escape
from rich.progress import BarColumn, MofNCompleteColumn, Progress, TextColumn, TimeElapsedColumn

from .terminal import printable


class SafeConsole(Console):
    """A rich console that strips control characters from every string it renders (table cells too):
    :func:`dualcal.terminal.printable`."""

    def render_str(self, text: str, *args, **kwargs):
        return super().render_str(printable(text), *args, **kwargs)


_stderr = SafeConsole(stderr=True)


@contextlib.contextmanager
def progress_bar(description: str, total: int, enabled: bool = True):
    """Context manager yielding ``advance(n=1)``; draws a bar on stderr when it is a terminal."""
    if not enabled or total <= 1:
        yield lambda n=1: None
        return
    with Progress(TextColumn("[bold]{task.description}"), BarColumn(), MofNCompleteColumn(),
                  TimeElapsedColumn(), console=_stderr, transient=True) as prog:
        task = prog.add_task(description, total=total)
        yield lambda n=1: prog.advance(task, n)


def track(items: Iterable, description: str, total: int | None = None, enabled: bool = True) -> Iterator:
    """Iterate over ``items`` with a progress bar on stderr."""
    items = list(items) if total is None else items
    with progress_bar(description, total if total is not None else len(items), enabled) as advance:
        for item in items:
            yield item
            advance()


def warn(message: str) -> None:
    """One warning line on stderr."""
    _stderr.print(f"[yellow]dualcal: warning:[/] {escape(printable(message))}", highlight=False, soft_wrap=True)
