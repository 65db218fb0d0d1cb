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
    assert "numpy" in loaded


@pytest.mark.parametrize("preset", ["stereo", "triple"])
def test_calibrating_corners_imports_only_what_it_uses(tmp_path, preset):
    """Issue 23: ``dualcal calibrate corners.json`` (its defaults) needs numpy and the terminal's
    libraries, not scipy (a third of a second to import), OpenCV, Pillow, matplotlib or jinja2; also
    where an ultra-wide is tried as a fisheye and a k1 k2 k3 lens started from Zhang's linear
    coefficients (``triple``: the fold of a cubic lens was found with scipy's root finder)."""
    from dualcal.files.io import save_corners
    from dualcal.synthetic.synth import make_truth, noisy_corner_set

    corners = tmp_path / "corners.json"
    save_corners(corners, noisy_corner_set(make_truth(preset, 6, seed=3), 0.1, seed=4))
    out, loaded = _loaded("calibrate", str(corners), "-o", str(tmp_path / "calib.json"))
    assert "written" in out
    assert loaded == {"numpy", "rich"}, f"calibrate imported {sorted(loaded)}"


def test_the_heic_and_dng_readers_load_only_for_a_photo_that_needs_them(tmp_path):
    """pillow-heif and rawpy (about 50 ms to import) are not loaded to read JPEGs; a HEIC read in a fresh
    process registers pillow-heif's opener itself."""
    import numpy as np
    from PIL import Image

    pytest.importorskip("pillow_heif").register_heif_opener()       # for Pillow to write HEIC here
    jpg, heic = tmp_path / "a.jpg", tmp_path / "b.heic"
    image = Image.fromarray(np.full((48, 64, 3), 200, np.uint8))
    image.save(jpg)
    image.save(heic, format="HEIF")
    code = ("import sys\n"
            "from dualcal.files.photos import read_exif, read_gray\n"
            "jpg, heic = sys.argv[1:]\n"
            "read_exif(jpg), read_gray(jpg)\n"
            "print(sorted({'pillow_heif', 'rawpy'} & set(sys.modules)))\n"
            "print(read_exif(heic)[0], read_gray(heic).shape, 'pillow_heif' in sys.modules, 'rawpy' in sys.modules)\n")
    out = subprocess.run([sys.executable, "-c", code, str(jpg), str(heic)], capture_output=True, text=True,
                         check=True).stdout.splitlines()
    assert out == ["[]", "(64, 48) (48, 64) True False"]


def test_the_collector_is_frozen_at_exit_once_the_command_is_done():
    """The interpreter's last collection skips what a command leaves (the exit handlers run before it): a handler
    registered before the command runs after the command's, and sees the objects frozen."""
    code = ("import atexit, gc\n"
            "atexit.register(lambda: print('frozen', gc.get_freeze_count() > 0))\n"
            "from dualcal.cli import main\n"
            "main(['--version'])\n")
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, check=False).stdout
    assert out.splitlines()[-1] == "frozen True", out
