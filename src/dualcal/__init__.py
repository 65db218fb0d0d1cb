"""dualcal: photogrammetric calibration of smartphone multi-camera rigs from chessboard photos.

The package is the API; the ``dualcal`` command is a thin shell over it::

    import dualcal
    corners = dualcal.load_corners("corners.json")            # or dualcal.detect_dataset(...)
    rig = dualcal.calibrate_rig(corners, skew=False, rig_mode="rigid")
    dualcal.save_rig("calib.json", rig)
    print(dualcal.evaluate(rig)["cases"])

Conventions (pixels, board, poses, omega-phi-kappa) are in the README, section "Conventions".
Names are imported on first use, so ``import dualcal`` stays light.
"""

__version__ = "0.1.0"

_API = {
    # data and models
    "Board": "board", "CameraModel": "camera", "Pose": "model", "CornerSet": "model",
    "CameraCorners": "model", "RigModel": "model", "RigRelation": "model",
    # the math
    "project_points": "camera", "undistort_points": "camera", "distort_points": "camera",
    "calibrate_rig": "calibrate", "triangulate": "intersect", "evaluate": "evaluation",
    "measure": "measurement",
    "undistort_image": "rectify", "rectified_camera": "rectify",
    "stereo_rectify": "stereo", "rectify_points": "stereo", "StereoRectification": "stereo",
    # the workflow every command runs
    "read_corners": "workflow", "calibrate_corners": "workflow", "evaluate_calibration": "workflow",
    "read_calibration": "workflow",
    # photos
    "open_dataset": "dataset", "detect_dataset": "detect", "detect_photo": "detect",
    # files
    "load_corners": "io", "save_corners": "io", "load_rig": "io", "save_rig": "io",
    "render_report": "report", "write_export": "export",
    # synthetic truth
    "make_truth": "synth", "noisy_corner_set": "synth", "truth_rig_model": "synth", "write_photo_set": "render",
    # errors
    "DualcalError": "errors", "InputError": "errors", "EstimationError": "errors",
    "NotInvertibleError": "errors", "DetectionError": "errors",
}

__all__ = sorted(_API) + ["__version__"]


def __getattr__(name):
    if name in _API:
        import importlib
        value = getattr(importlib.import_module(f".{_API[name]}", __name__), name)
        globals()[name] = value
        return value
    raise AttributeError(f"module 'dualcal' has no attribute {name!r}")


def __dir__():
    return __all__
