"""The bench configuration: one TOML file per bench, read with file:line:key errors."""
