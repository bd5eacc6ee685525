"""Helpers shared by test modules (and the benchmarks/ and fuzz/ scripts): import them as `tests.helpers.<module>`.

Test modules import helpers from here only, never from each other.
"""
