"""One run end to end: the runner and the sequencer's state machine with its safe stop."""
