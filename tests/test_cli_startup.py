"""Start-up: ``dualcal --version`` and ``--help`` import nothing heavy (checked on sys.modules, not on time)."""

import subprocess
import sys

import pytest

HEAVY = ("numpy", "scipy", "matplotlib", "cv2", "PIL", "jinja2", "rich")

PROBE = """
import sys
from dualcal.cli import main
try:
    main(sys.argv[1:])
except SystemExit:
    pass
print("loaded:", " ".join(sorted({m.split(".")[0] for m in sys.modules} & set(sys.argv[0].split(",")))))
"""


def _loaded(*args):
    res = subprocess.run([sys.executable, "-c", PROBE.replace("sys.argv[0]", repr(",".join(HEAVY))), *args],
                         capture_output=True, text=True, check=True)
    line = res.stdout.strip().splitlines()[-1]
    assert line.startswith("loaded:"), res.stdout
    return res.stdout, set(line[len("loaded:"):].split())


@pytest.mark.parametrize("args", [["--version"], ["--help"], ["detect", "--help"], ["measure", "--help"]])
def test_start_up_imports_nothing_heavy(args):
    out, loaded = _loaded(*args)
    assert "dualcal" in out
    assert loaded == set(), f"dualcal {' '.join(args)} imported {sorted(loaded)}"


def test_a_command_imports_its_library_when_it_runs():
    """The probe can fail: the help of a command with library choices loads that library."""
    _, loaded = _loaded("calibrate", "--help")
    assert "numpy" in loaded and "scipy" in loaded
