"""The damage-tolerant MCAP layer under `bench.log.reader`: the record framing, chunk decoding within limits,
and a walk over a file's records that reads around damage and says what it lost (`Damage`)."""
