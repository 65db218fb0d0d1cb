"""Files and photos: every JSON in and out and its schema, the photos read (EXIF, RAW), datasets and camera
rolls (and their identical files), the corners detected on them, the undistorted and rectified photos
written, the exports to other tools' formats, and the board to print (and which one).

A layer of dualcal (README, "Architecture"): its modules import only from it, the layers before it
(``dualcal._LAYERS``) and the cross-cutting modules at the top (``dualcal._CROSS_CUTTING``)."""
