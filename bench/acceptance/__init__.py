"""Acceptance of a calibration: limits from the configuration's `[acceptance]` and the verdict
(pass/fail with every check, its value and its limit) a result carries."""
