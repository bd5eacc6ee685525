"""Finishing a recorded run, live or re-solved: `finish(recorded, target)` (`bench.finish.finish`)."""
