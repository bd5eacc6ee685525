"""The MCAP run log: its format, the recorder that writes it, the tolerant reader, the run info it carries
and replay."""
