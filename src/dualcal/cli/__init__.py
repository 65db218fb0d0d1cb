"""The ``dualcal`` command: a thin shell over the library API.

Each sub-module registers its commands on :data:`cli`; the command modules import only click
at the top and the library inside each command, so ``dualcal --version`` and ``--help`` start
without numpy, OpenCV, scipy or matplotlib. Errors the user can cause
(:class:`~dualcal.errors.DualcalError`, bad flags) become one line on stderr and exit code 2;
Ctrl-C ends the command with one line and exit code 130 (worker pools stop at once, earlier
outputs stay as they were); an unexpected error says so in one line (the traceback only with
``--debug``) and exits 1. Every ``--help`` ends with the documentation's page to read, and an error's line
with the entry of its kind in *Checks and messages* (:mod:`dualcal.messages`).
"""

from __future__ import annotations

import atexit
import gc
import os
import signal
import sys
import threading

import click

from .. import __version__
from ..errors import DualcalError
from ..messages import DOCS, ERRORS, command_page, page_of
from ..terminal import printable


class DocumentedGroup(click.Group):
    """A group whose every command's ``--help`` ends with the documentation's page for it
    (:func:`dualcal.messages.command_page`), whichever module registers the command."""

    def add_command(self, cmd: click.Command, name: str | None = None) -> None:
        super().add_command(cmd, name)
        read = f"Documentation: {command_page(name or cmd.name)}"
        cmd.epilog = f"{cmd.epilog}\n\n{read}" if cmd.epilog else read


def error_line(exc: DualcalError) -> str:
    """``dualcal: error: MESSAGE (see docs/checks.md#inputerror)``: the error's entry is that of the nearest
    class of its kind that *Checks and messages* explains."""
    kind = next(c.__name__ for c in type(exc).__mro__ if c.__name__ in ERRORS)
    return f"dualcal: error: {printable(exc)} (see {page_of(kind)})"


@click.group(cls=DocumentedGroup, context_settings={"help_option_names": ["-h", "--help"]},
             epilog=f"Documentation: {DOCS}/index.md (make docs builds the site into out/site/)")
@click.version_option(__version__, prog_name="dualcal")
@click.option("--debug", is_flag=True, help="Show the full traceback of unexpected errors.")
def cli(debug: bool) -> None:
    """Calibrate a phone's multi-camera rig from chessboard photos.

    \b
    photos --detect--> corners.json --calibrate--> calib.json --evaluate--> eval.json
                                                              --report----> report.html
                                                              --rectify---> a stereo pair
                                                              --measure---> measure.json
    """


# Command modules register themselves on `cli` when imported.
from . import advise as _advise  # noqa: E402,F401
from . import app as _app  # noqa: E402,F401
from . import batch as _batch  # noqa: E402,F401
from . import board as _board  # noqa: E402,F401
from . import calibrate as _calibrate  # noqa: E402,F401
from . import detect as _detect  # noqa: E402,F401
from . import import_ as _import  # noqa: E402,F401
from . import evaluate as _evaluate  # noqa: E402,F401
from . import measure as _measure  # noqa: E402,F401
from . import rectify as _rectify  # noqa: E402,F401
from . import report as _report  # noqa: E402,F401
from . import schema as _schema  # noqa: E402,F401
from . import synth as _synth  # noqa: E402,F401


def _debug_requested(argv) -> bool:
    return "--debug" in argv or os.environ.get("DUALCAL_DEBUG") == "1"


def _interrupted() -> None:
    """One line and exit code 130; a second Ctrl-C while the workers wind down ends at once."""
    if threading.current_thread() is threading.main_thread():
        signal.signal(signal.SIGINT, lambda *_: os._exit(130))
    click.echo("dualcal: interrupted", err=True)
    sys.exit(130)


def main(argv=None) -> None:
    """Entry point of the console script."""
    argv = list(sys.argv[1:] if argv is None else argv)
    # The adjustment's matrices are small blocks, where OpenBLAS's worker threads cost more than they
    # give (calibrate on 13 instants: 0.85 s with them, 0.77 s without); detection runs photos in
    # threads of its own. Set before numpy loads; a value the user set is kept.
    os.environ.setdefault("OPENBLAS_NUM_THREADS", "1")
    # At the interpreter's exit its last collection walks every object a command left (a calibration's arrays,
    # every module's): 0.02-0.03 s of a calibration's 0.4 s. The command's outputs are written and closed by then,
    # and what it leaves goes with the process: frozen just before that collection (the exit handlers run first),
    # they are skipped. Registered once, however often main runs in one process.
    atexit.unregister(gc.freeze)
    atexit.register(gc.freeze)
    try:
        cli.main(args=argv, prog_name="dualcal", standalone_mode=False)
    except (click.exceptions.Abort, KeyboardInterrupt):
        _interrupted()
    except click.exceptions.ClickException as exc:  # usage errors: exit code 2
        exc.show()
        sys.exit(2)
    except DualcalError as exc:
        click.echo(error_line(exc), err=True)
        sys.exit(2)
    except BrokenPipeError:                 # e.g. `dualcal calibrate ... | head`: the reader left
        sys.stderr.close()
        sys.exit(1)
    except Exception as exc:  # a bug in dualcal, not in the input
        if _debug_requested(argv):
            raise
        click.echo(f"dualcal: internal error: {type(exc).__name__}: {printable(exc)} "
                   "(run again with --debug for the traceback)", err=True)
        sys.exit(1)
    sys.exit(0)
