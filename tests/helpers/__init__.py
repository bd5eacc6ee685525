"""Helpers shared by test modules (and tests/benchmarks scripts): import them as `tests.helpers.<module>`.

Test modules import helpers from here only, never from each other.
"""
