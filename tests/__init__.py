"""The test suite as a package, so that `tests.helpers` imports the same way under pytest and from scripts."""
