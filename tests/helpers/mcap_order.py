"""How far an MCAP file is from log-time order, as `mcap doctor` (the reference CLI) looks at it."""

from __future__ import annotations

from mcap.reader import make_reader


def log_time_order(path) -> tuple[dict[str, int], dict[str, int]]:
    """In file order: per topic, (how many of its messages have an older log time than the topic's message before
    them, how many have an older log time than the newest of any topic before them: `mcap doctor`'s warning)."""
    own, behind, last, newest = {}, {}, {}, 0
    with open(path, "rb") as f:
        for _schema, channel, message in make_reader(f).iter_messages(log_time_order=False):
            t, topic = message.log_time, channel.topic
            own[topic] = own.get(topic, 0) + (t < last.get(topic, 0))
            behind[topic] = behind.get(topic, 0) + (t < newest)
            last[topic], newest = t, max(newest, t)
    return own, behind
