"""Markdown and HTML reports of a calibration result, with plots and comparisons."""
