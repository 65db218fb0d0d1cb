"""What became of every photo of a calibration (kept, dropped and why, left out, board not found) and its
row in the per-photo tables of the terminal, the report and the app. Light: no numerical library beyond the
rig's own arrays."""

from __future__ import annotations

from ..geometry.model import RigModel, observed_mask


def photo_status(rig: RigModel) -> dict[str, dict[str, tuple[float | None, str]]]:
    """``[view][camera] -> (rms_px or None, status)`` for every photo of the calibration's corners.

    The status is ``"kept"``, ``"board not found"``, ``"dropped: <why>"`` (the start of the
    calibration's reason; the RMS is the one the photo had when it was dropped), ``"left out by
    --exclude"`` or ``"not used"`` (corners but no pose, e.g. no other camera saw that instant).
    """
    dropped = {(d.get("camera"), d.get("view")): d for d in rig.dropped_views if isinstance(d, dict)}
    out: dict[str, dict[str, tuple[float | None, str]]] = {}
    for cam in rig.camera_order():
        corners = rig.corners.cameras[cam]
        for view in corners.meta.get("excluded", {}):
            out.setdefault(view, {})[cam] = (None, "left out by --exclude")
        for view, uv in corners.views.items():
            if uv is None or not observed_mask(uv).any():
                entry = (None, "board not found")
            elif view in rig.camera_poses.get(cam, {}):
                entry = (rig.view_rms_px.get(view, {}).get(cam), "kept")
            elif (cam, view) in dropped:
                d = dropped[(cam, view)]
                entry = (d.get("rms_px"), "dropped: " + str(d.get("reason", "outlier")).split(";")[0].split(" (")[0])
            else:
                entry = (None, "not used")
            out.setdefault(view, {})[cam] = entry
    return dict(sorted(out.items()))


#: A photo is noted as blurred where its squares' edges (corners.json ``meta.photo_quality``: ``blur_px``, the
#: corner fit's edge width) are more than ``BLURRED_TIMES`` as wide as in the median photo of its camera (a
#: photo out of focus, or shaken), or wider than ``BLURRED_EDGE_PX`` (about a Gaussian blur of 3 px: edges spread
#: over 10 px and more, as a defocused 8 MP photo's); a note only: its corners are kept, and the calibration
#: weighs them by their noise.
BLURRED_TIMES = 2.0
BLURRED_EDGE_PX = 4.0


def photo_quality(rig: RigModel) -> dict[str, dict[str, tuple[float, float, bool]]]:
    """``[view][camera] -> (blur_px, corner_noise_px, blurred)`` for every photo whose detection measured them
    (corners.json ``meta.photo_quality``; see :data:`BLURRED_TIMES` for ``blurred``); empty for corners
    detected before dualcal measured them."""
    out: dict[str, dict[str, tuple[float, float, bool]]] = {}
    for cam in rig.camera_order():
        quality = rig.corners.cameras[cam].meta.get("photo_quality") or {}
        blurs = sorted(q["blur_px"] for q in quality.values())
        if not blurs:
            continue
        typical = blurs[len(blurs) // 2]
        for view, q in quality.items():
            blurred = q["blur_px"] > BLURRED_TIMES * typical or q["blur_px"] > BLURRED_EDGE_PX
            out.setdefault(view, {})[cam] = (float(q["blur_px"]), float(q["corner_noise_px"]), bool(blurred))
    return out


def photo_rows(status: dict, names: list[str], missing: str = "-",
               quality: dict | None = None) -> list[tuple[str, list[str], str]]:
    """The rows of the per-photo table from :func:`photo_status`: ``(view, RMS per camera in
    ``names`` order, status)``, ``missing`` where a camera has no RMS for the view. With ``quality``
    (:func:`photo_quality`), each row's cells go on with ``"blur / noise"`` (px) per camera, and its status
    notes the blurred photos."""
    rows = []
    for view, per in status.items():
        cells = [f"{per[n][0]:.3f}" if n in per and per[n][0] is not None else missing for n in names]
        notes = [f"{n}: {per[n][1]}" for n in names if n in per and per[n][1] != "kept"]
        blurred = []
        if quality is not None:
            q = quality.get(view, {})
            cells += [f"{q[n][0]:.1f} / {q[n][1]:.3f}" if n in q else missing for n in names]
            blurred = [f"{n}: blurred (edges {q[n][0]:.1f} px wide, corner noise {q[n][1]:.2f} px)"
                       for n in names if n in q and q[n][2]]
        rows.append((view, cells, "; ".join([*(notes or ["kept"]), *blurred])))
    return rows
