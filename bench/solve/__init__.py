"""From observations to coefficients: least-squares methods, calibrate, extraction from a log, the budget
inputs (re-solving recorded logs and comparing methods are in `bench.jobs`)."""
