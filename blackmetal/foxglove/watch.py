"""Who watches what: the Foxglove topics clients subscribe to, and the Zenoh keys the view needs for them (pure).

A view nobody watches costs almost nothing (issue #29; docs/foxglove.md, "Only what is watched"): the host
declares a subscriber on a key only while a client (or the MCAP file) takes a channel that key feeds.
"""

from __future__ import annotations

from collections import defaultdict
from collections.abc import Iterable, Mapping


class Watch:
    """Subscriptions per topic, and the keys they need, given which topics each key feeds."""

    def __init__(self, feeds: Mapping[str, Iterable[str]], record_all: bool = False) -> None:
        """``feeds``: Zenoh key -> the Foxglove topics its samples are shown on; ``record_all``: an MCAP file takes every channel."""
        self.feeds = {key: frozenset(topics) for key, topics in feeds.items()}
        self.record_all = record_all
        self._clients: dict[str, set[int]] = defaultdict(set)

    def subscribe(self, client: int, topic: str) -> bool:
        """A client subscribed to ``topic``; True when that is the topic's first subscriber."""
        first = not self._clients[topic]
        self._clients[topic].add(client)
        return first

    def unsubscribe(self, client: int, topic: str) -> bool:
        """A client unsubscribed (or left); True when nobody watches ``topic`` any more."""
        watchers = self._clients.get(topic)
        if not watchers or client not in watchers:
            return False
        watchers.discard(client)
        if not watchers:
            del self._clients[topic]
        return not watchers

    def client_gone(self, client: int) -> list[str]:
        """The topics nobody watches any more once ``client`` left."""
        return [topic for topic in list(self._clients) if self.unsubscribe(client, topic)]

    def watched(self, topic: str) -> bool:
        return self.record_all or topic in self._clients

    def needed(self) -> set[str]:
        """The keys that feed a watched topic (every key while an MCAP file records)."""
        if self.record_all:
            return set(self.feeds)
        watched = self._clients.keys()
        return {key for key, topics in self.feeds.items() if not topics.isdisjoint(watched)}
