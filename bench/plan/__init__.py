"""Procedures as data: step records, sequencer events, the plan compiler and the visiting order."""
