"""The 3-D view and flight.rrd in Rerun. Only :mod:`gcs.view.scene` is free of the optional
extra; the rest imports ``rerun`` (``pip install 'quadswarm[view]'``)."""
