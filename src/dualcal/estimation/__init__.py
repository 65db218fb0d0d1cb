"""The estimation: the joint adjustment and its solver, the covariance and its honest sigmas, outliers and
model choice, instants that repeat another's view, the checks of a calibration, and what a calibration
measures (intersection, evaluation, measurement, advice on the next photo). Pure computation on the
geometry's types: it reads and writes no file.

A layer of dualcal (README, "Architecture"): its modules import only from it, the layers before it
(``dualcal._LAYERS``) and the cross-cutting modules at the top (``dualcal._CROSS_CUTTING``)."""
