"""From observations to coefficients: least-squares methods, calibrate, extraction from a log,
re-solve and method comparison."""
