"""What every check, error and message of dualcal means, its likely cause and what to do: one table.

The documentation's page *Checks and messages* (``docs/checks.md``) is generated from this table, the
commands' ``--help`` ends with the page to read (:data:`COMMAND_PAGES`), and an error line names the
entry of its kind (:func:`page_of`). ``tests/test_messages.py`` finds every check name that the code
writes into calib.json's ``checks``, every error class and every ``dualcal: ...`` line the command prints
from the code itself, and fails where one has no entry here: a new check cannot ship without its page.

Each entry is a dict:

``title``     a few words;
``meaning``   what it says, for the person with a phone;
``cause``     its likely causes;
``action``    what to do;
``examples``  (optional) fragments of messages the code prints for it, each found in the source by the test.

Nothing here imports anything: the commands' ``--help`` reads this module.
"""

__all__ = ["DOCS", "CHECKS", "ERRORS", "LINES", "COMMAND_PAGES", "page_of", "command_page"]

DOCS = "docs"
"""Where the documentation's pages are: the built site's pages are named by their source file under ``docs/``
(``make docs`` builds them into ``out/site/``, ``checks.md`` becoming ``checks.html``)."""

CHECKS_PAGE = "checks.md"
"""The page of this table, relative to :data:`DOCS`."""

CHECKS = {
    "converged": {
        "title": "the adjustment converged",
        "meaning": "The joint adjustment (the least-squares fit of every camera, the rig and every board position "
                   "to the corners) reached its best fit. When it fails, the numbers in calib.json are not those of "
                   "the best fit and their sigmas mean little. No statistical limit: the optimiser's own tests.",
        "cause": "Very few photos, photos that all show the board the same way (all square-on, or all at one "
                 "distance), a photo whose corners were found wrongly and pulls the fit, or a rig mode that does "
                 "not suit the photos (`--rig paper` on a few noisy instants needs many more iterations).",
        "action": "Read the photo table that `dualcal calibrate` prints: leave out a photo whose RMS stands out "
                  "with `--exclude`, add photos with the board tilted in different directions, or calibrate the "
                  "cameras alone first (`--rig none`) to see which camera has trouble.",
        "examples": ["the adjustment did not converge"],
    },
    "photos": {
        "title": "enough board positions",
        "meaning": "At least 8 instants (board positions, each photographed by the cameras that see it). dualcal's "
                   "sigmas come from how the instants disagree with each other; with fewer than 8 that scatter, and "
                   "so every sigma, is itself uncertain.",
        "cause": "Too few positions shot, or photos left out: board not found, dropped as outliers, excluded.",
        "action": "Shoot 12-20 positions with the board tilted 30-50 degrees in different directions and reaching "
                  "the corners of the frame (see *How to shoot*), or ask `dualcal advise` where to hold the board "
                  "next.",
        "examples": ["only ", "instants: 10-20, the board tilted"],
    },
    "fit": {
        "title": "the lens model fits the corners",
        "meaning": "Every camera's RMS reprojection error (the distance between where a corner was found and where "
                   "the calibration puts it, 2-D, per corner) is below 1 px. Sharp photos of a flat, true board fit "
                   "to 0.02-0.3 px.",
        "cause": "A board that is not flat (paper that bows, a board leaning on a wall) or not printed true, blurred "
                 "or moving photos, corners found wrongly, or a lens the model cannot describe.",
        "action": "The sigmas already account for it, but look at the report's residual plots and the photo table: "
                  "glue the board flat to something stiff, leave out blurred photos with `--exclude`, lock focus.",
        "examples": ["far above what corner detection achieves"],
    },
    "rig_rigid": {
        "title": "the cameras kept their relative pose",
        "meaning": "The photos of every instant fit one fixed relative pose of the cameras (the rig's baseline and "
                   "angles). Two statistical tests, with a stated false-alarm rate: on a synchronised rig one "
                   "calibration in a hundred fails by chance (`false_alarm_rate` 0.01, split over the tests). Each "
                   "instant's tie cost (how far its own relative pose of the cameras, with every camera alone, is from "
                   "the relation the other instants tell, in its photos' noise) is judged against a robust core of the "
                   "other instants: the instants that each pass the test against the rest of the core, found so that "
                   "two or three bad instants can neither pull the relation nor widen the scatter the others are "
                   "judged by (`statistic`: "
                   "the worst instant's tie cost over the core's typical one, `limit`: that ratio at its test's limit; "
                   "`instant_f`: every instant's ratio, t, p-value and limit; `core_instants`). The instants together "
                   "are judged against the photo-level noise, how much more the photos disagree than white noise on "
                   "the corners would allow (`ratio` against `limit_ratio`, an F quantile; calib.json "
                   "`design_effect`). The message names every instant that does not fit, with its ratio and p-value. "
                   "Named instants fail the check only where leaving them out moves the rig's baseline or angles by "
                   "more than twice their sigma (`shift_sigma` against `shift_limit_sigma`); a smaller misfit is named "
                   "and kept. An instant whose misfit one photo's focal change explains is a refocus, which `focus` names "
                   "(`refocused`).",
        "cause": "The board or the phone moved between the shots of one position (not on a tripod, a board held "
                 "by hand, a board that slid, a tap on the screen), the lenses did not shoot at the same instant, a "
                 "lens that moved (optical image stabilisation, a refocus), or photos of different positions put "
                 "into one instant. A board held by hand and cameras that are not triggered together show as an "
                 "instant or two at small p-values, even where the misfit is a fraction of a pixel.",
        "action": "Leave out the instants it names with `--exclude INSTANT` (every camera's photo of it) and "
                  "calibrate again, or shoot them again from a tripod with a remote or the timer, the board still. "
                  "If every instant fails, the shots are not synchronised: use a tripod and shoot each position "
                  "with every lens before moving the board.",
        "examples": ["do not fit the rig's relative pose", "worse than the photo-level noise allows",
                     "against the other instants' scatter", "x the others' tie cost", "false-alarm rate"],
    },
    "focus": {
        "title": "no photo refocused",
        "meaning": "No photo has a focal length of its own, and no camera's photos have two. Each photo's focal "
                   "scale, fitted with its board pose, is judged against a robust core of its camera's other photos "
                   "by a Student t test (`statistic`: the largest |t|, `limit`: the t quantile), so that two or three "
                   "refocused photos cannot hide each other; each camera's photos are also split into two groups of "
                   "focal lengths, the best split judged against the splits of chance (`splits`: a camera of two "
                   "lenses fails). The false-alarm rate is one calibration in a hundred with a fixed focus "
                   "(`false_alarm_rate` 0.01, split over the tests). A photo whose own corners fix its focal length "
                   "no better than 5 % (few corners, a board small or square-on: `not_judged`, `not_judged_limit`) "
                   "is not judged: it could not show a refocus, and its focal scale would be a guess.",
        "cause": "Autofocus ran between the shots (the board at another distance, a tap on the screen), a digital "
                 "zoom step (an iPhone's 2x) mixed with the lens's own, or two lenses of one image size taken for "
                 "one camera (a camera roll without EXIF).",
        "action": "Lock focus and exposure (AE/AF lock: a long press on the board in the stock camera app) and "
                  "shoot again, or leave the named photos out with `--exclude CAMERA/PHOTO`; for a camera of two "
                  "focal lengths, give each lens its own camera (its own folder).",
        "examples": ["have a focal length of their own", "against its camera's other photos", "have two focal lengths",
                     "not judged: their own corners fix the focal length only to"],
    },
    "determination": {
        "title": "every parameter is known well enough",
        "meaning": "Each focal length is known to 1 %, each principal point to 1 % of the image, the lens "
                   "distortion at the outermost corner measured to 0.5 px, each baseline to 2 % and each relative "
                   "angle to 30 minutes of arc (all 1-sigma). The message names what is not, with what would help. These limits "
                   "are what a calibration is used for, not statistical (no false-alarm rate).",
        "cause": "Photos that show the board only in the middle of the frame, all square-on, or all at one "
                 "distance; a tele that sees the board in few instants.",
        "action": "Do what the message says (tilt the board, bring it to the corners of the frame), or run "
                  "`dualcal advise calib.json -o advise.json` for the board positions that shrink these sigmas most.",
        "examples": ["known only to", "every parameter is well determined"],
    },
    "lens_model": {
        "title": "the lens model has the terms the lens needs",
        "meaning": "The residuals (what the calibration cannot explain) at the image's edge are at most twice those "
                   "at its centre. Where they grow towards the edge, the lens model lacks terms. The limit (2 x) is a fixed "
                   "one, not statistical (no false-alarm rate): on sharp photos a model with the terms it needs keeps "
                   "the ratio near 1.",
        "cause": "A lens with more distortion than the chosen model describes: an ultra-wide calibrated with two "
                 "radial terms, a lens with decentring (tangential) distortion, or a board that is not flat.",
        "action": "Let dualcal choose the model (`--model auto`, the default) or give a richer one: `--model "
                  "k1k2p1p2k3`, or `kb4` for a fisheye ultra-wide. The report's residual plots show where the "
                  "residuals grow.",
        "examples": ["the lens model misses terms"],
    },
    "scale_plausible": {
        "title": "the board's square size is believable",
        "meaning": "Every length (the baseline, the board's distance, measured lengths) scales with the square size "
                   "you gave, which no other check can test. Where the photos' EXIF shows a phone's small sensor, "
                   "this check asks whether the board's distance (0.15-5 m) and the lenses' spacing (5-40 mm) are a "
                   "phone's. Without those EXIF facts there is no such check, and `calibrate` says that the scale "
                   "rests on `--square` alone.",
        "cause": "`--square` in the wrong unit (3 for 30 mm, or centimetres), the size of another board, or a "
                 "board printed scaled (\"fit to page\").",
        "action": "Measure ten squares of the printed board with a ruler; `--square` is that length over ten, and "
                  "`--square-sigma` what you trust of it (0.05 mm with a good ruler and a careful eye).",
        "examples": ["is the board's", "apart, where a"],
    },
    "loop_closure": {
        "title": "three or more cameras agree with each other",
        "meaning": "For a rig of three or more cameras: every pair of cameras, taken alone, tells the rig's story. "
                   "Every instant two cameras both saw shows their relative pose (each photo with its own board pose); "
                   "for each pair, those poses scatter about their mean as their photos' noise allows (`pairs`: "
                   "`ratio` against `limit_ratio`), and for a pair of two non-reference cameras their mean agrees with "
                   "the relation the rig composes through the reference (`loops`: the misclosure, its `t2` against "
                   "`limit`). Statistical tests at a stated false-alarm rate, one calibration in a hundred on a rigid "
                   "rig (`false_alarm_rate` 0.01, split over the tests). A pair's scatter is taken over its robust core "
                   "of instants (`core_instants`; those `apart` fail it only where they move its relation by more "
                   "than 2 sigma, `shift_sigma`). A pair sharing fewer than 3 instants whose relative pose is known "
                   "to a degree (a board small or far in a photo is not) is not judged (`not_judged`).",
        "cause": "A camera that moved between instants (a lens with stabilisation, a knock): it fails every pair it "
                 "belongs to, which names it.",
        "action": "Find the instants with `rig_rigid`'s message, leave them out with `--exclude` or shoot them "
                  "again; make sure every pair of cameras sees the board in at least 3 instants, better 8.",
        "examples": ["do not fit one rigid relation", "in each: it moved between instants?",
                     "pairwise relative poses agree with the rig", "shared instants whose relative pose is known to"],
    },
    "intrinsics_prior": {
        "title": "the photos agree with the intrinsics known for a camera",
        "meaning": "Where some cameras' intrinsics were given (an earlier calibration of each camera from its own "
                   "photos, a peer's file), each is calibrated again from its photos alone and compared with what "
                   "was given, within both their sigmas: a chi-square test at a stated false-alarm rate.",
        "cause": "The lens changed since the intrinsics were found (refocused, another zoom, a lens or a case moved, "
                 "the phone dropped), or the intrinsics given are another camera's or another resolution's.",
        "action": "Calibrate the camera named again from its own photos (or give its intrinsics with their "
                  "covariance, so that the photos may move them); check that the file names the right camera.",
        "examples": ["disagree with the intrinsics known for", "the photos agree with the known intrinsics"],
    },
}
"""The checks of a calibration (calib.json ``checks``, the end of ``dualcal calibrate``'s output, the top of the
report), keyed by their name in calib.json."""

ERRORS = {
    "DualcalError": {
        "title": "any error the input causes",
        "meaning": "The base of all the errors below: the command stopped because of its input, printed one line "
                   "saying what is wrong, wrote nothing (an earlier output stays as it was) and exited with code 2.",
        "cause": "See the more specific errors below.",
        "action": "Read the line: it names the file, flag or photo and what to do.",
    },
    "InputError": {
        "title": "a file, folder, flag or JSON document is wrong",
        "meaning": "A file, folder, flag or JSON document is missing, malformed or does not fit the others.",
        "cause": "A typo in a path or flag; a folder holding both photos and subfolders; cameras whose photos pair "
                 "with none of the reference camera's; a JSON file edited by hand that breaks its schema (the line "
                 "names the key); an eval.json of another calibration; a photo too large to be one; a camera roll "
                 "without EXIF whose lenses of one image size the photos cannot tell apart (their focal lengths and "
                 "bends within 5 sigma of each other, or scattering more than one lens's without a gap).",
        "action": "Do what the line says. `dualcal schema NAME` prints the schema of a JSON file; `dualcal COMMAND "
                  "--help` lists the flags.",
        "examples": ["pair with none of", "must be greater than 1", "was computed from another calibration than",
                     "which lens took which photo cannot be told"],
    },
    "EstimationError": {
        "title": "an estimate could not be made",
        "meaning": "The photos do not determine what was asked: too few views, a degenerate configuration, an "
                   "adjustment that cannot start.",
        "cause": "Too few photos where the board was found; every photo with the board parallel to the others "
                 "(the intrinsics need tilted views); two photos with no corner in common for a measurement.",
        "action": "Add photos with the board tilted 30-50 degrees in different directions; check with `dualcal "
                  "detect` that the board is found in most photos.",
        "examples": ["the board poses are (nearly) parallel to each other", "needs at least"],
    },
    "NotInvertibleError": {
        "title": "a lens model that folds over",
        "meaning": "A lens model could not be inverted where it was asked: its distortion folds over (the radius "
                   "stops growing), so a pixel there has no single ray.",
        "cause": "Distortion coefficients extrapolated beyond the corners the photos measured (a lens calibrated "
                 "only in the middle of its frame), or a file edited by hand.",
        "action": "Calibrate with photos that bring the board to the corners of the frame, or keep outputs within "
                  "the measured part of the image (`--keep valid`).",
    },
    "DetectionError": {
        "title": "no board could be found",
        "meaning": "No chessboard was found in a photo, or the grid found failed its own checks (its colours, its "
                   "corners against their neighbours). In a dataset such a photo is skipped with a warning naming "
                   "it; the error stops the command only where no photo is left.",
        "cause": "A wrong `--board` (it counts inner corners: a board of 9 x 6 squares is `8x5`), the board cut "
                 "off by the frame, glare, blur so strong that OpenCV's detectors do not find the board either "
                 "(a blurred board they find is kept: its corners are noisier, and the photo table says so), or a "
                 "board too small in the photo.",
        "action": "Count the inner corners again; `dualcal detect --overlays DIR` draws what was found on each "
                  "photo; where detection fails, `dualcal pick` lets you click the board's four outer corners.",
        "examples": ["chessboard found"],
    },
    "PartialBoard": {
        "title": "only part of a symmetric board is in the photo",
        "meaning": "Only part of a plain chessboard is in the photo, and its corners cannot be numbered: a board "
                   "whose columns plus rows is even looks the same turned by 180 degrees, so it must be seen whole.",
        "cause": "The board reaching beyond the frame, typically in the tele.",
        "action": "Keep the whole board in every lens's frame, print a board whose columns plus rows is odd "
                  "(`dualcal board` chooses one), or use a ChArUco board, which may be seen in part.",
        "examples": ["only part of the"],
    },
    "OutputError": {
        "title": "an output cannot be written",
        "meaning": "An output file cannot be written: nothing was replaced, an earlier result stays whole.",
        "cause": "A full disk, a read-only or missing folder.",
        "action": "Free space or choose another output path.",
        "examples": ["disk is full"],
    },
}
"""The errors: every failure the input can cause is one of these (``dualcal.errors``, and the detector's own);
the command prints ``dualcal: error: MESSAGE (see PAGE)`` and exits with code 2."""

LINES = {
    "warning": {
        "title": "dualcal: warning: ...",
        "meaning": "Something was skipped or is worth knowing, and the command goes on: a file that is not a "
                   "photo, a photo where the board was not found, a retake kept in place of an earlier photo, a "
                   "board numbered by a guess.",
        "cause": "Named in the line.",
        "action": "Read it once: a photo skipped is not used; if too many are, the checks say so.",
        "examples": ["that are not photos", "retake: "],
    },
    "error": {
        "title": "dualcal: error: ...",
        "meaning": "The input is wrong (one of the errors above, named at the end of the line). Exit code 2; "
                   "nothing was written.",
        "cause": "Named in the line.",
        "action": "Do what the line says; the page it names explains the kind of error.",
    },
    "internal error": {
        "title": "dualcal: internal error: ...",
        "meaning": "A bug in dualcal, not in your input. Exit code 1; nothing half-written is left.",
        "cause": "dualcal met a case it does not handle.",
        "action": "Run the same command again with `dualcal --debug COMMAND ...` to see the traceback, and report "
                  "it with the command line.",
    },
    "interrupted": {
        "title": "dualcal: interrupted",
        "meaning": "Ctrl-C stopped the command (exit code 130). The worker threads stop at once and nothing is "
                   "written after it; earlier outputs stay as they were.",
        "cause": "Ctrl-C, or the terminal closed.",
        "action": "Run it again: `dualcal batch` skips the devices it had finished.",
    },
}
"""The lines the command prints besides its results, keyed by their prefix after ``dualcal: ``."""

COMMAND_PAGES = {
    "advise": "how-to/advise.md",
    "app": "how-to/app.md",
    "batch": "how-to/fleet.md",
    "board": "how-to-shoot.md",
    "calibrate": "getting-started.md",
    "detect": "how-to-shoot.md",
    "evaluate": "reading-results.md",
    "export": "how-to/export.md",
    "import": "how-to/import.md",
    "measure": "how-to/measure.md",
    "pick": "how-to/manual.md",
    "rectify": "how-to/rectify.md",
    "report": "reading-results.md",
    "schema": "reference/formats/index.md",
    "synth": "getting-started.md",
    "undistort": "how-to/rectify.md",
}
"""The page each command's ``--help`` ends with, relative to :data:`DOCS`; a command not listed here gets its
entry of the command-line reference (:func:`command_page`)."""


def _anchor(name: str) -> str:
    """The heading's anchor of an entry on the page (the lower-cased name, spaces as dashes)."""
    return name.lower().replace(" ", "-")


def page_of(name: str) -> str:
    """The documentation's address of the entry ``name`` (a check, an error class or a line's prefix).

    Parameters
    ----------
    name : str
        A key of :data:`CHECKS`, :data:`ERRORS` or :data:`LINES`.

    Returns
    -------
    str
        ``docs/checks.md#rig_rigid``: the page and the entry's anchor.

    Raises
    ------
    KeyError
        Where ``name`` has no entry.
    """
    if name not in CHECKS and name not in ERRORS and name not in LINES:
        raise KeyError(name)
    return f"{DOCS}/{CHECKS_PAGE}#{_anchor(name)}"


def command_page(command: str) -> str:
    """The documentation's page to read for ``dualcal COMMAND``.

    Parameters
    ----------
    command : str
        The command's name, e.g. ``measure``.

    Returns
    -------
    str
        Its page (:data:`COMMAND_PAGES`, else its entry of the command-line reference), e.g.
        ``docs/how-to/measure.md``.
    """
    page = COMMAND_PAGES.get(command)
    return f"{DOCS}/{page}" if page else f"{DOCS}/reference/cli.md#dualcal-{command}"
