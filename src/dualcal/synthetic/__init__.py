"""Synthetic truth: rigs, rolls and fleets with known parameters and photo-like renders of them, the test
bed of the estimation and of the files.

A layer of dualcal (README, "Architecture"): its modules import only from it, the layers before it
(``dualcal._LAYERS``) and the cross-cutting modules at the top (``dualcal._CROSS_CUTTING``)."""
