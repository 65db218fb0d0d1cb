"""Files and photos: every JSON in and out and its schema, the photos read (EXIF, RAW), datasets and camera
rolls, their duplicates, the corners detected on them, and the undistorted and rectified photos written.
It speaks in the geometry's types and knows nothing of the estimation.

A layer of dualcal (README, "Architecture"): its modules import only from it, the layers before it
(``dualcal._LAYERS``) and the cross-cutting modules at the top (``dualcal._CROSS_CUTTING``)."""
