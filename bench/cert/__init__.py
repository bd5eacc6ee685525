"""Calibration certificates (issue 32 items 4 and 6): what a certificate states (`content`), gathered from the
records database and the run's log; rendered as a PDF (`pdf`) and as a PTB Digital Calibration Certificate
(`dcc`, validated against the DCC 3.1.2 schema shipped in `schemas/`); and checked against the records (`check`)."""
