"""Monte Carlo of a fisheye rig's sigmas: phone3's wide (k1k2p1p2k3) + fisheye ultra-wide (kb4).

Synthetic corners (``noisy_corner_set``, white noise), rigid rig, flat board: the spread of
error / sigma (calib.json's sigma, and the textbook sigma_formal) per parameter over the draws, and
pooled over the intrinsics and over the rig. An honest sigma spreads by 1 (0.8-1.25 with these
draws). Usage: ``python benchmarks/bench_fisheye_sigma.py [DRAWS]`` (default 40, about a minute).
"""

import sys
import time

import numpy as np

from dualcal.calibrate import calibrate_rig
from dualcal.synth import make_truth, noisy_corner_set


def main(draws: int = 40) -> None:
    full = make_truth("phone3", 12, seed=5)
    truth = type(full)(full.board, {n: full.cameras[n] for n in ("wide", "ultra")}, full.reference,
                       {"ultra": full.rig["ultra"]}, full.view_poses)
    z = {"sigma": {}, "sigma_formal": {}}
    start = time.perf_counter()
    for k in range(draws):
        rig = calibrate_rig(noisy_corner_set(truth, 0.2, seed=500 + k), model={"wide": "k1k2p1p2k3", "ultra": "kb4"},
                            drop_outliers=False, board_shape="flat")
        for which, sigma in (("sigma", rig.camera_sigma), ("sigma_formal", rig.camera_sigma_formal)):
            for name, cam in rig.cameras.items():
                for p in ("fx", "fy", "cx", "cy", *(("k1", "k2", "k3", "k4") if cam.fisheye else ("k1", "k2", "k3"))):
                    err = getattr(cam, p) - getattr(truth.cameras[name], p)
                    z[which].setdefault(f"{name}.{p}", []).append(err / sigma[name][p])
            rel, true = rig.rig["ultra"], truth.rig["ultra"]
            s = (rel.sigma_baseline_mm, rel.sigma_opk_arcmin) if which == "sigma" else \
                (rel.sigma_formal["baseline_mm"], np.asarray(rel.sigma_formal["opk_arcmin"]))
            z[which].setdefault("ultra.baseline_mm", []).append((rel.baseline_mm - np.linalg.norm(true.t_mm)) / s[0])
            for axis, e in zip("opk", (rel.pose.opk_arcmin - true.opk_arcmin) / s[1]):
                z[which].setdefault(f"ultra.{axis}_arcmin", []).append(e)
    print(f"{draws} draws, {time.perf_counter() - start:.0f} s; spread (sd) of error / sigma")
    print(f"{'parameter':22s} {'sigma':>8s} {'formal':>8s}")
    for key in z["sigma"]:
        print(f"{key:22s} {np.std(z['sigma'][key], ddof=1):8.2f} {np.std(z['sigma_formal'][key], ddof=1):8.2f}")
    for group, test in (("intrinsics", lambda k: not k.startswith("ultra.") or k[6:] in
                         ("fx", "fy", "cx", "cy", "k1", "k2", "k3", "k4")), ("rig", lambda k: k.startswith("ultra.")
                                                                            and k[6:] not in ("fx", "fy", "cx", "cy", "k1", "k2", "k3", "k4"))):
        pooled = {w: np.concatenate([v for k, v in z[w].items() if test(k)]) for w in z}
        print(f"{'pooled ' + group:22s} {np.std(pooled['sigma'], ddof=1):8.2f} {np.std(pooled['sigma_formal'], ddof=1):8.2f}")


if __name__ == "__main__":
    main(int(sys.argv[1]) if len(sys.argv) > 1 else 40)
