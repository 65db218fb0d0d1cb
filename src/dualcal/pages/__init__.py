"""The HTML pages: the report, the fleet, the pick page for measuring and the advice page.

A layer of dualcal (README, "Architecture"): its modules import only from it, the layers before it
(``dualcal._LAYERS``) and the cross-cutting modules at the top (``dualcal._CROSS_CUTTING``)."""
