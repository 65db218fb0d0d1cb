"""Monte Carlo of a fisheye rig's sigmas: phone3's wide (k1k2k3) + fisheye ultra-wide (kb4).

Synthetic corners (``noisy_corner_set``, white noise of NOISE px), rigid rig, flat board: the
spread of error / sigma (calib.json's sigma, and the textbook sigma_formal) per parameter over the
draws, and pooled over the intrinsics and over the rig. An honest sigma spreads by 1 (0.8-1.25
with 40 draws). Usage: ``python benchmarks/bench_fisheye_sigma.py [DRAWS [NOISE]]`` (default 40
draws of 0.05 px; 3-4 minutes on a busy 2-core machine).
"""

import sys
import time

import numpy as np

from dualcal.estimation.calibrate import calibrate_rig
from dualcal.synthetic.synth import make_truth, noisy_corner_set


def main(draws: int = 40, noise_px: float = 0.05) -> None:
    full = make_truth("phone3", 12, seed=5)
    truth = type(full)(full.board, {n: full.cameras[n] for n in ("wide", "ultra")}, full.reference,
                       {"ultra": full.rig["ultra"]}, full.view_poses)
    z = {"sigma": {}, "sigma_formal": {}}
    start = time.perf_counter()
    for k in range(draws):
        rig = calibrate_rig(noisy_corner_set(truth, noise_px, seed=500 + k), model={"wide": "k1k2k3", "ultra": "kb4"},
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
    print(f"{draws} draws of {noise_px} px, {time.perf_counter() - start:.0f} s; spread (sd) of error / sigma")
    print(f"{'parameter':22s} {'sigma':>8s} {'formal':>8s}")
    for key in z["sigma"]:
        print(f"{key:22s} {np.std(z['sigma'][key], ddof=1):8.2f} {np.std(z['sigma_formal'][key], ddof=1):8.2f}")
    rig_keys = {"ultra.baseline_mm", "ultra.o_arcmin", "ultra.p_arcmin", "ultra.k_arcmin"}
    for group, keys in (("intrinsics", [k for k in z["sigma"] if k not in rig_keys]), ("rig", sorted(rig_keys))):
        pooled = {w: np.concatenate([z[w][k] for k in keys]) for w in z}
        print(f"{'pooled ' + group:22s} {np.std(pooled['sigma'], ddof=1):8.2f} {np.std(pooled['sigma_formal'], ddof=1):8.2f}")


if __name__ == "__main__":
    main(*(int(sys.argv[1]),) if len(sys.argv) > 1 else (), *(float(sys.argv[2]),) if len(sys.argv) > 2 else ())
