"""Start-up time of the ``dualcal`` command against a bare ``python -c "import numpy"``, in the same run.

Prints the median wall time of ``dualcal --version``, ``dualcal --help`` and ``python -c "import numpy"``
over ``--runs`` runs each (interleaved, so machine load hits all alike) and the ratios. Target: within a
few times the numpy import.

Also, for the end-to-end comparison (``bench_end_to_end.py``): a process that imports what ``dualcal calibrate
photos/`` imports before its first photo (the commands, the workflow, detection, the calibration) against one that
imports what OpenCV's pipeline does (numpy and cv2), and their ratio.
"""

from __future__ import annotations

import argparse
import shutil
import statistics
import subprocess
import sys
import time
from pathlib import Path

#: What ``dualcal calibrate photos/`` imports before it reads its first photo.
CALIBRATE_IMPORTS = ("import dualcal.cli, dualcal.workflow, dualcal.files.detect.pipeline, "
                     "dualcal.estimation.calibrate, dualcal.estimation.adjust")


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--runs", type=int, default=15)
    args = parser.parse_args()
    dualcal = shutil.which("dualcal", path=str(Path(sys.executable).parent)) or "dualcal"
    commands = {"dualcal --version": [dualcal, "--version"], "dualcal --help": [dualcal, "--help"],
                "python -c 'import numpy'": [sys.executable, "-c", "import numpy"],
                "calibrate's imports": [sys.executable, "-c", CALIBRATE_IMPORTS],
                "python -c 'import numpy, cv2'": [sys.executable, "-c", "import numpy, cv2"]}
    times = {name: [] for name in commands}
    for _ in range(args.runs):
        for name, cmd in commands.items():
            t0 = time.perf_counter()
            subprocess.run(cmd, check=True, capture_output=True)
            times[name].append(time.perf_counter() - t0)
    base = statistics.median(times["python -c 'import numpy'"])
    print(f"{'command':28s} {'median (s)':>10s} {'/ import numpy':>15s}")
    for name, t in times.items():
        print(f"{name:28s} {statistics.median(t):10.3f} {statistics.median(t) / base:15.2f}")
    ratio = statistics.median(times["calibrate's imports"]) / statistics.median(times["python -c 'import numpy, cv2'"])
    print(f"calibrate's imports / OpenCV pipeline's (numpy, cv2): {ratio:.2f}")


if __name__ == "__main__":
    main()
