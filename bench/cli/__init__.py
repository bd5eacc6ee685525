"""The `bench` command line: `main` wires one module per command; nothing outside this package imports it."""
