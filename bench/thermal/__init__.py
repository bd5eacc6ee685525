"""Calibration over temperature: per-temperature results -> per-coefficient polynomials in temperature."""
