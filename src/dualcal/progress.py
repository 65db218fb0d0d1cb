"""Progress bars and warnings on stderr (stdout stays free for data).

Warnings of the library go through the ``logging`` logger ``"dualcal"`` (:func:`warn`). Its one
handler, :data:`STDERR_HANDLER`, prints each as one line ``dualcal: warning: ...`` on stderr, for the
command line and for a user of the API alike; the logger does not propagate, so a program that
configures logging for itself does not see each warning twice (remove the handler to route them
elsewhere). :func:`collect_warnings` gathers them instead, as ``batch`` does for each device.
"""

from __future__ import annotations

import contextlib
import logging
from collections.abc import Iterable, Iterator

from rich.console import Console
from rich.markup import escape

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
    from rich.progress import BarColumn, MofNCompleteColumn, Progress, TextColumn, TimeElapsedColumn

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


LOGGER = logging.getLogger("dualcal")


class _StderrHandler(logging.Handler):
    """A warning as one line on stderr, ``dualcal: warning: MESSAGE``."""

    def emit(self, record: logging.LogRecord) -> None:
        _stderr.print(f"[yellow]dualcal: warning:[/] {escape(record.getMessage())}", highlight=False,
                      soft_wrap=True)


class _Collector(logging.Handler):
    def __init__(self, messages: list[str]):
        super().__init__(logging.WARNING)
        self.messages = messages

    def emit(self, record: logging.LogRecord) -> None:
        self.messages.append(record.getMessage())


STDERR_HANDLER = _StderrHandler(logging.WARNING)
LOGGER.addHandler(STDERR_HANDLER)
LOGGER.setLevel(logging.WARNING)
LOGGER.propagate = False


def warn(message: str) -> None:
    """A warning of the library: one line on stderr (or into :func:`collect_warnings`)."""
    LOGGER.warning(message)


@contextlib.contextmanager
def collect_warnings() -> Iterator[list[str]]:
    """Collect the library's warnings into the list yielded, instead of printing them."""
    messages: list[str] = []
    collector = _Collector(messages)
    before = list(LOGGER.handlers)        # stderr, or an outer collection: none of them sees these until said again
    for handler in before:
        LOGGER.removeHandler(handler)
    LOGGER.addHandler(collector)
    try:
        yield messages
    finally:
        LOGGER.removeHandler(collector)
        for handler in before:
            LOGGER.addHandler(handler)
