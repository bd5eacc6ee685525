"""The damage-tolerant MCAP layer under `bench.log.reader`: `walk.walk(buf)` reads every record of a file it can,
reads around damage and says what it lost (`Walk.damage`: `Damage` entries, one line each with `describe`).

Modules, bottom up: `records` (the record layout, chunk headers, resync after damage, framing a chunk by its
message index, letting a mapped file's pages go), `parts` (where one channel's messages of one chunk are
held: the `Part` protocol), `chunks` (decompression within limits, chunks kept compressed until asked for,
the prefetch on worker threads), `channel` (`ChannelData`: one channel's parts), `damage`, `keep` (what of the
messages a walk gathers outlives it), `walk`.
A refused chunk raises `ChunkRefused` inside the package; what leaves it is `Damage`, or `WalkError` for
a file that is not MCAP at all.
"""

from bench.log.mcap.channel import ChannelData
from bench.log.mcap.chunks import InflateBudget, inflated_or_refusal
from bench.log.mcap.damage import Damage
from bench.log.mcap.parts import InChunk, MessageCut, Part
from bench.log.mcap.records import ChunkRefused, WalkError
from bench.log.mcap.walk import MAX_DBC_BYTES, Walk

__all__ = ["MAX_DBC_BYTES", "ChannelData", "ChunkRefused", "Damage", "InChunk", "InflateBudget", "MessageCut",
           "Part", "Walk", "WalkError", "inflated_or_refusal"]

# `walk` itself is `bench.log.mcap.walk.walk`: the name here stays the module's (tests patch its limits)
