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


def photo_rows(status: dict, names: list[str], missing: str = "-") -> list[tuple[str, list[str], str]]:
    """The rows of the per-photo table from :func:`photo_status`: ``(view, RMS per camera in
    ``names`` order, status)``, ``missing`` where a camera has no RMS for the view."""
    rows = []
    for view, per in status.items():
        cells = [f"{per[n][0]:.3f}" if n in per and per[n][0] is not None else missing for n in names]
        notes = [f"{n}: {per[n][1]}" for n in names if n in per and per[n][1] != "kept"]
        rows.append((view, cells, "; ".join(notes) or "kept"))
    return rows
