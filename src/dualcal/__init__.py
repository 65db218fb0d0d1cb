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

#: The layers of the library, in order: a module imports only from its own layer, those before it and
#: the cross-cutting modules beside this file (README, "Architecture"; tests/test_layout.py).
_LAYERS = ("geometry", "estimation", "files", "synthetic", "pages")
_CROSS_CUTTING = ("errors", "extras", "messages", "parallel", "progress", "terminal")

_API = {
    # data and models
    "Board": "geometry.board", "CameraModel": "geometry.camera", "Pose": "geometry.model",
    "CornerSet": "geometry.model",
    "CameraCorners": "geometry.model", "RigModel": "geometry.model", "RigRelation": "geometry.model",
    "KnownIntrinsics": "geometry.model",
    # the math
    "project_points": "geometry.camera", "undistort_points": "geometry.camera", "distort_points": "geometry.camera",
    "calibrate_rig": "estimation.calibrate", "triangulate": "estimation.intersect", "evaluate": "estimation.evaluation",
    "measure": "estimation.measurement",
    "undistort_image": "files.rectify", "rectified_camera": "files.rectify",
    "stereo_rectify": "files.stereo", "rectify_points": "files.stereo", "StereoRectification": "files.stereo",
    # the workflow every command runs
    "read_corners": "workflow", "calibrate_corners": "workflow", "evaluate_calibration": "workflow",
    "read_calibration": "workflow",
    # photos
    "open_dataset": "files.dataset", "detect_dataset": "files.detect", "detect_photo": "files.detect",
    # files
    "load_corners": "files.io", "save_corners": "files.io", "load_rig": "files.io", "save_rig": "files.io",
    "render_report": "pages.report", "write_export": "files.export",
    "import_files": "files.imports", "read_known_intrinsics": "files.imports", "load_intrinsics": "files.io",
    "save_intrinsics": "files.io",
    # synthetic truth
    "make_truth": "synthetic.synth", "noisy_corner_set": "synthetic.synth", "truth_rig_model": "synthetic.synth",
    "write_photo_set": "synthetic.render", "write_caliscope_session": "synthetic.synth_caliscope",
    # errors
    "DualcalError": "errors", "InputError": "errors", "EstimationError": "errors",
    "NotInvertibleError": "errors", "DetectionError": "errors",
}

__all__ = sorted(_API) + ["__version__"]


def _lazy_names(package: str, api: dict[str, str], public: list[str]):
    """``__getattr__`` and ``__dir__`` (PEP 562) for ``package``, whose names ``api`` (``{name: module}``,
    relative to it) are imported from their modules on first use and kept; ``public``: its ``__all__``."""
    def __getattr__(name):
        if name in api:
            import importlib
            import sys

            value = getattr(importlib.import_module(f".{api[name]}", package), name)
            setattr(sys.modules[package], name, value)
            return value
        raise AttributeError(f"module {package!r} has no attribute {name!r}")

    return __getattr__, lambda: public


__getattr__, __dir__ = _lazy_names(__name__, _API, __all__)
