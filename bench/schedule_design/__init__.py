"""Designing schedules: first-order sensitivities, Monte Carlo, exhaustive search and plan recommendation."""
