"""Verification of a calibration on data the fit did not use (`bench verify`, `[plan] verification`)."""
