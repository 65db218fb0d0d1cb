"""``dualcal app``: the local web app, above the layers beside :mod:`dualcal.cli`.

A project is a folder of the files the commands write (:mod:`.store`); what it computes is what
``dualcal detect`` and ``dualcal calibrate`` compute for its photos, through :mod:`dualcal.workflow`
(:mod:`.work`, run by :mod:`.jobs` in worker processes so that the server's event loop never
computes). :mod:`.server` holds the routes (parse, authorise, call), :mod:`.security` the token and
the Host and Origin rules, :mod:`.uploads` the streamed, size-limited, safely named uploads,
:mod:`.summary` what a page shows of a calibration. Nothing in the library imports this package.
"""
