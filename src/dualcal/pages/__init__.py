"""Pages and text: the HTML report (and the fleet, pick and advice pages), the paper's tables for the
terminal, the exports to other tools' formats, the printable board and the choice of a board to print.

A layer of dualcal (README, "Architecture"): its modules import only from it, the layers before it
(``dualcal._LAYERS``) and the cross-cutting modules at the top (``dualcal._CROSS_CUTTING``)."""
