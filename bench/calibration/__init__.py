"""Using a calibration: the compensation a navigation computer applies, its export formats,
applying it to a run log's samples (`bench export`, `bench apply`)."""
