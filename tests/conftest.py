"""Shared test helpers: the real data folder and running the CLI in-process."""

from __future__ import annotations

import fcntl
import os
import pickle
import shutil
from pathlib import Path

import pytest

SHARED_DATA = Path(__file__).resolve().parents[2] / "shared" / "data"
CHROMIUM = next((p for p in (shutil.which("chromium"), shutil.which("chromium-browser"),
                             "/usr/bin/chromium") if p and Path(p).exists()), None)


@pytest.fixture
def shared_data():
    """``../shared/data`` beside the repository; tests using it skip where it is absent."""
    if not SHARED_DATA.is_dir():
        pytest.skip(f"real photos not available: {SHARED_DATA} does not exist")
    return SHARED_DATA


@pytest.fixture(scope="session")
def shared_tmp(tmp_path_factory) -> Path:
    """A folder every test worker (pytest-xdist) sees: the parent of their base temporary folders."""
    base = tmp_path_factory.getbasetemp()
    return base.parent if os.environ.get("PYTEST_XDIST_WORKER") else base


@pytest.fixture(scope="session")
def computed_once(shared_tmp):
    """``computed_once(key, compute)``: ``compute()`` once for the whole run, shared by the test workers
    (pytest-xdist): the first worker to ask computes and pickles it under a lock, the others load it. For
    fixtures that cost many seconds (real photos detected, Monte Carlo draws, a page's commands run) and
    would otherwise be computed again in every worker that runs one of their tests."""
    shared = shared_tmp

    def once(key: str, compute):
        path = shared / f"once-{key}.pickle"
        with open(shared / f"once-{key}.lock", "w") as lock:
            fcntl.flock(lock, fcntl.LOCK_EX)
            if not path.exists():
                value = compute()
                path.write_bytes(pickle.dumps(value))
                return value
        return pickle.loads(path.read_bytes())

    return once


class CliResult:
    def __init__(self, code, out, err):
        self.code, self.out, self.err = code, out, err

    def __iter__(self):
        return iter((self.code, self.out, self.err))

    @property
    def err_lines(self):
        return [line for line in self.err.splitlines() if line.strip()]


@pytest.fixture(scope="module")
def browser():
    """Headless Chromium (the system's, driven by Playwright) for the pages' tests; they skip where it is absent."""
    if CHROMIUM is None:
        pytest.skip("no Chromium here to render the page (Debian: apt-get install chromium); "
                    "the page's other checks still ran")
    sync_api = pytest.importorskip("playwright.sync_api", reason="playwright (test extra) drives Chromium")
    with sync_api.sync_playwright() as pw:
        browser = pw.chromium.launch(executable_path=CHROMIUM, args=[
            "--no-sandbox", "--disable-gpu", "--disable-quic", "--no-first-run", "--disable-background-networking",
            "--disable-component-update", "--disable-sync"])
        yield browser
        browser.close()


@pytest.fixture
def run_cli(capsys):
    """Run ``dualcal ARGS...`` in-process; returns exit code, stdout and stderr."""
    from dualcal.cli import main

    def run(*args):
        capsys.readouterr()
        with pytest.raises(SystemExit) as exc:
            main([str(a) for a in args])
        captured = capsys.readouterr()
        return CliResult(exc.value.code, captured.out, captured.err)

    return run


@pytest.fixture(autouse=True)
def every_calibration_converges(request, monkeypatch):
    """Issue 12: every calibration in the suite reports ``converged: true``. A test that forces a
    solve not to converge says so with ``@pytest.mark.not_converged``."""
    if request.node.get_closest_marker("not_converged"):
        return
    from dualcal.estimation import calibrate, fitting

    package = fitting.rig_model_from_solution

    def checked(sol, *args, **kwargs):
        rig = package(sol, *args, **kwargs)
        assert rig.adjustment["converged"], f"a calibration did not converge: {rig.adjustment['termination']}"
        return rig

    for module in (calibrate, fitting):                 # a calibration, and a solution packaged alone
        monkeypatch.setattr(module, "rig_model_from_solution", checked)
