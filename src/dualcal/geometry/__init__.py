"""The geometry: the camera and lens models, the boards, rotations and poses, the data that flows between the
stages, and the closed forms on them (homographies and Zhang's initial calibration, space resection), the
grid of a board's corners in a photo, and which points a camera sees. It imports nothing of the other layers.

A layer of dualcal (README, "Architecture"): its modules import only from it, the layers before it
(``dualcal._LAYERS``) and the cross-cutting modules at the top (``dualcal._CROSS_CUTTING``)."""
