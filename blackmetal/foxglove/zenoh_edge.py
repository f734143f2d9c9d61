"""Zenoh edge of the Foxglove view: declarations only, payloads handed over to the view on its loop."""

from __future__ import annotations

import asyncio

from blackmetal.runtime.edge import Handover, ZenohEdge

from .core import LiveView


class FoxgloveZenoh(ZenohEdge):
    """Subscribes to every key the view shows (:meth:`LiveView.handlers`)."""

    def attach(self, view: LiveView, loop: asyncio.AbstractEventLoop) -> Handover:
        handover = Handover(loop)
        for key, handler in view.handlers().items():
            self.subscriber(key, handover.channel(key, handler, capacity=512))
        return handover
