"""Calibration records: a database of units, runs, results and coefficients (SQLAlchemy Core; SQLite by default).

`store` opens it and records and queries, `schema` and `migrate` define and version it,
`ingest` reads result files and logs on disk into it, `history` analyses a unit over time, `lab` keeps the
equipment register, review and sign-off in an append-only audit trail.
"""
