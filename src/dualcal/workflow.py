"""The one workflow under every command: input -> corners -> calibration -> evaluation.

Each step here is what a command, :mod:`dualcal.batch` and a user of the Python API call, so that
the same input gives the same files whichever way it came in:

* :func:`read_corners`: a ``corners.json`` as it is (less the views ``exclude`` leaves out) or a
  dataset of photos through detection: one loader, one board check (:func:`check_board`), the
  dataset's pair check (:func:`dualcal.files.dataset.check_pairs`); a camera roll (or a folder of photos
  without EXIF) is split into cameras and instants after its photos are detected, each once.
* :func:`calibrate_corners`: :func:`dualcal.estimation.calibrate.calibrate_rig` and the comparison of lens
  models by held-out instants, recorded in the calibration (calib.json ``adjustment.lens_models``).
* :func:`read_intrinsics`, :func:`known_intrinsics_for`: the cameras' intrinsics known before a calibration
  (``--intrinsics FILE``), checked against the corners they are for.
* :func:`evaluate_calibration`: the paper's stereo-intersection check as eval.json's content,
  stamped with the fingerprint of the calibration it checked (``calibration_fingerprint``).
* :func:`read_calibration`: a calib.json, refused when its corners do not fit its parameters.

Errors a user can cause are :class:`~dualcal.errors.InputError` (bad input) or
:class:`~dualcal.errors.EstimationError` (input that cannot be calibrated); their messages name
the input, never a command-line flag. Warnings go through :func:`dualcal.progress.warn`.
"""

from __future__ import annotations

from dataclasses import asdict, replace
from pathlib import Path

from .geometry.board import Board
from .errors import EstimationError, InputError
from .geometry.model import CornerSet, KnownIntrinsics, RigModel
from .progress import warn

__all__ = ["DETECTION_OPTIONS", "calibrate_corners", "check_board", "evaluate_calibration", "known_intrinsics_for",
           "lens_scores", "read_calibration", "read_corners", "read_intrinsics"]

#: Options of :func:`read_corners` that only apply to a dataset of photos (detection).
DETECTION_OPTIONS = ("jobs", "hints_path", "overlays_dir", "detect")


def check_board(given: Board | None, found: Board, source: str) -> Board:
    """The board ``source`` (a corners.json) names, after checking that ``given`` (if any) is it.

    :meth:`Board.matches` decides (a ChArUco board's dictionary and layout are compared only where
    ``given`` has them); the message names what differs.

    Raises
    ------
    InputError
        ``given`` is another board than ``found``.
    """
    if given is None:
        return found
    if not given.matches(found):
        if (given.spec(), given.cols, given.rows) != (found.spec(), found.cols, found.rows):
            what = f"board {given.spec()} disagrees with {source}, which has {found.spec()}"
        elif abs(given.square_mm - found.square_mm) > 1e-9 * found.square_mm:
            what = f"square {given.square_mm:g} mm disagrees with {source}, which has {found.square_mm:g} mm"
        elif None not in (given.charuco, found.charuco) and given.charuco.marker_mm != found.charuco.marker_mm:
            what = (f"marker {given.charuco.marker_mm:g} mm disagrees with {source}, which has "
                    f"{found.charuco.marker_mm:g} mm")
        else:
            what = f"{given.describe(sizes=True)} disagrees with {source}, which has {found.describe(sizes=True)}"
        raise InputError(f"{what}: give the board of that file, or none")
    return found


def _is_corners_file(source) -> bool:
    return source is not None and Path(source).is_file()


def read_corners(source=None, board: Board | None = None, *, square_sigma_mm: float | None = None,
                 cameras=(), pair_by: str = "stem",
                 time_tolerance_s: float = 2.0, instant_gap_s: float | None = None, reference: str | None = None,
                 exclude=(), jobs: int | None = None, hints_path=None, overlays_dir=None,
                 progress: bool = True, detect=None) -> CornerSet:
    """The corners of an input: a corners.json, a dataset folder, or cameras given as ``NAME=GLOB``.

    Parameters
    ----------
    source
        a corners.json, a dataset folder (:func:`dualcal.files.dataset.open_dataset`; a camera roll too, and a
        flat folder of photos without EXIF, as a phone's browser uploads them, whose cameras and instants the
        detected boards tell: :func:`dualcal.files.dataset.split_roll_dataset`), or None when ``cameras`` are given.
    board : Board or None
        the board; needed for photos, checked against a corners.json's (:func:`check_board`).
    square_sigma_mm : float or None
        the 1-sigma of the printed square's size (:attr:`Board.square_sigma_mm`), recorded
        with the board; None keeps what the board or the corners.json says.
    cameras, pair_by, time_tolerance_s, instant_gap_s, reference
        how a dataset's photos are found and
        grouped into instants (:func:`dualcal.files.dataset.open_dataset`).
    exclude
        glob patterns of photos to leave out (:func:`dualcal.files.dataset.is_excluded`), for a
        dataset and a corners.json alike; they are listed in each camera's ``excluded``.
    jobs, hints_path, overlays_dir, progress, detect
        detection (:func:`dualcal.files.detect.detect_dataset`); for a
        corners.json they do not apply (a warning says so).

    Raises
    ------
    InputError
        A missing input, a file given with cameras from globs, photos without a board, a board that
        disagrees with the corners.json, and every refusal of :func:`~dualcal.files.dataset.open_dataset`,
        :func:`~dualcal.files.dataset.check_pairs` and :func:`~dualcal.files.io.load_corners`.

    Returns
    -------
    CornerSet
        corners.json's content: the board and every camera's corners per view.
    """
    if _is_corners_file(source) and cameras:
        raise InputError(f"{source} is a file, but cameras given by globs take photos: give a dataset folder "
                         "(or nothing) with them, or the corners.json alone")
    if source is not None and not cameras and not Path(source).exists():
        raise InputError(f"{source}: no such file or folder (give a dataset folder of photos, or a corners.json)")
    if source is None and not cameras:
        raise InputError("no input: give a corners.json, a dataset folder, or cameras with their photos")
    if not _is_corners_file(source):
        if board is None:
            raise InputError(f"{source or 'the photos'}: a dataset of photos needs the board (its corners "
                             "COLSxROWS, or charuco:SXxSY with the marker size) and the square size")
        corners = _detect(source, board, cameras=cameras, pair_by=pair_by, time_tolerance_s=time_tolerance_s,
                          instant_gap_s=instant_gap_s, reference=reference, exclude=exclude, jobs=jobs,
                          hints_path=hints_path, overlays_dir=overlays_dir, progress=progress, detect=detect)
    else:
        from .files.io import load_corners

        ignored = [name for name, value in zip(DETECTION_OPTIONS, (jobs, hints_path, overlays_dir, detect)) if value]
        if ignored:
            warn(f"{source} is a corners.json: the detection options ({', '.join(ignored)}) do not apply to it")
        corners = load_corners(source)
        corners = replace(corners, board=check_board(board, corners.board, str(source)))
        if reference is not None:
            corners = replace(corners, reference=reference)
        if exclude:
            from .files.dataset import exclude_views      # (it reads photos: not imported for a corners.json alone)
            corners = exclude_views(corners, exclude)
    if square_sigma_mm is not None:
        corners = replace(corners, board=replace(corners.board, square_sigma_mm=float(square_sigma_mm)))
    return corners


def _detect(source, board: Board, *, cameras, pair_by, time_tolerance_s, instant_gap_s, reference, exclude,
            jobs, hints_path, overlays_dir, progress, detect) -> CornerSet:
    """A dataset's corners: open it, refuse cameras that pair with nothing, detect; a camera roll, or a folder
    of photos without EXIF, is split into cameras and instants once its boards are detected (each photo is
    detected once, before the split); clips: their frames chosen and measured
    (:func:`dualcal.files.video.video_corners`)."""
    from .files.dataset import check_pairs, open_dataset, split_roll_dataset
    from .files.detect import detect_dataset, load_hints
    from .files.video import find_clips, video_corners

    clips = find_clips(source, cameras)
    if clips is not None:
        return video_corners(clips, board, reference=reference, progress=progress)

    dataset = open_dataset(source, cameras, pair_by=pair_by, reference=reference,
                           time_tolerance_s=time_tolerance_s, instant_gap_s=instant_gap_s, exclude=exclude)
    if not dataset.split_pending:
        check_pairs(dataset, pair_by)
    hints = load_hints(hints_path) if hints_path else None
    corners = detect_dataset(dataset, board, jobs=jobs, hints=hints, overlays_dir=overlays_dir, progress=progress,
                             detect=detect)
    if dataset.split_pending:
        dataset, corners = split_roll_dataset(dataset, corners)
        check_pairs(dataset, pair_by)
    return replace(corners, reference=reference) if reference is not None else corners


def read_intrinsics(paths) -> dict[str, KnownIntrinsics]:
    """The cameras' known intrinsics in ``paths``, files ``calibrate --intrinsics`` takes (a calib.json, an
    intrinsics.json, a peer's file: :func:`dualcal.files.imports.read_known_intrinsics`).

    Parameters
    ----------
    paths : iterable of str or Path
        The files.

    Returns
    -------
    dict of str to KnownIntrinsics
        By camera name, from every file.

    Raises
    ------
    InputError
        A missing or unreadable file, or one camera named by two of them.
    """
    if not paths:
        return {}
    from .files.imports import read_known_intrinsics      # the peers' formats, loaded only where one is read

    known: dict[str, KnownIntrinsics] = {}
    for path in paths:
        for name, camera in read_known_intrinsics(path).items():
            if name in known:
                raise InputError(f"camera {name!r} has known intrinsics in both {known[name].source} and {path}: "
                                 "give each camera once")
            known[name] = camera
    return known


def known_intrinsics_for(corners: CornerSet, known: dict[str, KnownIntrinsics]) -> dict[str, KnownIntrinsics]:
    """The known intrinsics of the cameras of ``corners``, each checked against its corners' image size; the
    cameras ``known`` names that ``corners`` does not have are warned of and left out.

    Parameters
    ----------
    corners : CornerSet
        The corners to calibrate (:func:`read_corners`).
    known : dict of str to KnownIntrinsics
        Known intrinsics by camera name (:func:`read_intrinsics`).

    Returns
    -------
    dict of str to KnownIntrinsics
        Those of the cameras of ``corners``.

    Raises
    ------
    InputError
        A camera whose known intrinsics are of another image size than its photos.
    """
    unknown = sorted(set(known) - set(corners.cameras))
    if unknown:
        warn(f"{', '.join(unknown)}: known intrinsics of no camera here (cameras: "
             f"{', '.join(sorted(corners.cameras))}): not used (rename the camera in the file, or when importing "
             "with --rename, to use them)")
    for name in sorted(set(known) & set(corners.cameras)):
        given, photos = known[name].camera.image_size, corners.cameras[name].image_size
        if tuple(given) != tuple(photos):
            turned = " (the photos are stored turned)" if tuple(given) == tuple(photos)[::-1] else ""
            raise InputError(f"camera {name!r}: its known intrinsics ({known[name].source}) are of {given[0]} x "
                             f"{given[1]} px images, its photos {photos[0]} x {photos[1]} px{turned}: give the "
                             "intrinsics of this camera at this image size")
    return {name: k for name, k in known.items() if name in corners.cameras}


def calibrate_corners(corners: CornerSet, *, compare_lens: bool = True, model="auto", **options) -> RigModel:
    """Calibrate a rig from its corners, with the lens models compared by held-out instants.

    ``options`` are those of :func:`dualcal.estimation.calibrate.calibrate_rig` (``skew``, ``rig_mode``,
    ``reference``, ``drop_outliers``, ``outlier_factor``, ``board_shape``); corners from clips whose clocks
    could not all be matched (:mod:`dualcal.files.video`) are calibrated with every lens alone. ``model`` is as
    there, but ``"auto"`` by default, as for the commands: each camera's lens model chosen by its held-out instants
    (:func:`dualcal.estimation.model_selection.choose_lens_models`, recorded in the calibration). With one lens model
    for every camera and ``compare_lens``, every other model is scored on instants left out of the
    calibration (:func:`dualcal.estimation.model_selection.compare_lens_models`) and the scores are recorded in
    ``rig.adjustment["lens_models"]`` (calib.json); a comparison that cannot be made is a warning.

    Parameters
    ----------
    corners : CornerSet
        The corners (:func:`read_corners`).
    compare_lens : bool
        With one lens model for every camera: score every other model on instants left out.
    model : str or Mapping[str, str]
        ``"auto"``, a lens model's name for every camera, or ``{camera: name}``.
    **options
        Those of :func:`dualcal.estimation.calibrate.calibrate_rig` (``known_intrinsics`` among them:
        :func:`known_intrinsics_for`).

    Returns
    -------
    RigModel
        The calibration, calib.json's content.

    Raises
    ------
    InputError
        An unknown lens model or option.
    EstimationError
        Too few usable views, degenerate views, no view shared by the cameras of a rig.
    """
    from .estimation.calibrate import calibrate_rig
    from .estimation.model_selection import compare_lens_models

    from .files.io import video_record

    unmatched = (video_record(corners) or {}).get("unmatched")
    if unmatched and options.get("rig_mode", "rigid") != "none":
        warn(f"the clocks of {', '.join(unmatched)} could not be matched to the reference's (the board was never "
             "seen moving by both at once): every lens is calibrated alone (rig mode none)")
        options["rig_mode"] = "none"
    alone = corners.cameras_alone()
    if alone and len(corners.cameras) > 1 and options.get("rig_mode", "rigid") != "none":
        warn(f"the corners of {', '.join(alone)} are of recordings where each camera filmed the board alone "
             "(caliscope's intrinsic session): their instants are no moments the cameras share; every lens is "
             "calibrated alone (rig mode none)")
        options["rig_mode"] = "none"
    rig = calibrate_rig(corners, model=model, **options)
    if compare_lens and model != "auto" and rig.model != "mixed":
        try:
            rig.adjustment["lens_models"] = [asdict(s) for s in compare_lens_models(rig)]
        except EstimationError as exc:
            warn(f"the lens models could not be compared: {exc}")
    return rig


def other_skew_model(rig: RigModel) -> RigModel:
    """``rig`` with the other skew model (the paper's Model 2 beside Model 1, or back), to show them side by
    side: the same corners, lens models, rig mode and board shape, adjusted from ``rig``'s values
    (:func:`dualcal.estimation.fitting.refit`), with its sigmas and no checks of its own."""
    from .estimation.fitting import refit, rig_model_from_solution

    return rig_model_from_solution(refit(rig, skew=not rig.skew), rig.corners, rig.dropped_views, rig.dropped_corners)


def lens_scores(rig: RigModel) -> list:
    """The comparison of one lens model for every camera that :func:`calibrate_corners` recorded in ``rig``
    (empty without one, and for ``"auto"``, whose choice camera by camera is ``adjustment["lens_models_chosen"]``)."""
    from dataclasses import fields

    from .estimation.model_selection import LensModelScore

    if "lens_models_chosen" in rig.adjustment:
        return []
    keys = {f.name for f in fields(LensModelScore)}
    return [LensModelScore(**{k: v for k, v in s.items() if k in keys}) for s in rig.adjustment.get("lens_models", [])]


def evaluate_calibration(rig: RigModel, holdout: bool = False, progress: bool = True) -> dict:
    """eval.json's content: the paper's stereo-intersection check (:func:`dualcal.estimation.evaluation.evaluate`)
    with the fingerprint of the calibration it checked (``calibration_fingerprint``).

    Parameters
    ----------
    rig : RigModel
        The calibration.
    holdout : bool
        Orient each view with a calibration that left it out.
    progress : bool
        Draw a progress bar on stderr.

    Returns
    -------
    dict
        eval.json's content: ``cases`` (``dual`` and one per camera, each ``rmse_mm`` and ``pairs``), the
        pose-free length check and ``calibration_fingerprint``.
    """
    from .estimation.evaluation import evaluate
    from .files.io import calibration_fingerprint

    return {**evaluate(rig, holdout=holdout, progress=progress), "calibration_fingerprint": calibration_fingerprint(rig)}


def read_calibration(path) -> RigModel:
    """A calib.json (:func:`dualcal.files.io.load_rig`), refused when its corners do not fit its parameters
    (:func:`dualcal.files.io.check_corners_fit`: corners of another calibration pasted in).

    Parameters
    ----------
    path : str or Path
        The calib.json to read.

    Returns
    -------
    RigModel
        The calibration.

    Raises
    ------
    InputError
        A file that breaks a rule of calib.json, or corners that do not fit its parameters.
    """
    from .files.io import check_corners_fit, load_rig

    rig = load_rig(path)
    check_corners_fit(rig, str(path))
    return rig
