"""One module per ``fgcal`` command: each a thin layer over the library (see :mod:`fgcal.cli`)."""
