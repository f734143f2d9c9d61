"""The view's host: where it listens, a port in use or an unwritable file in one sentence, the clients' subscriptions told to the view.

Each test runs a host on a free port of the loopback, on its own loop; no Zenoh.
"""

from __future__ import annotations

import asyncio
from pathlib import Path

import pytest

from blackmetal.foxglove.host import FoxgloveHost
from blackmetal.foxglove.naming import StatusLevel
from blackmetal.foxglove.settings import FoxgloveSettings
from blackmetal.foxglove.watch import Watch
from blackmetal.schemas import ConfigError


class Viewer:
    def __init__(self) -> None:
        self.watch = Watch({"robot/pose": {"/pose"}})
        self.subscribed_to: list[str] = []
        self.changes = 0

    def subscribed(self, topic: str) -> None:
        self.subscribed_to.append(topic)

    def watch_changed(self) -> None:
        self.changes += 1


def test_the_host_listens_where_asked_and_a_port_in_use_is_one_sentence() -> None:
    async def main() -> None:
        host = FoxgloveHost(FoxgloveSettings(port=0))
        try:
            await host.start()
            assert host.port > 0 and host.url == f"ws://127.0.0.1:{host.port}"
            assert host.server.port != host.port, "the SDK listens behind the front"
            taken = FoxgloveHost(FoxgloveSettings(port=host.port))
            with pytest.raises(ConfigError, match=rf"cannot serve Foxglove on 127\.0\.0\.1:{host.port} .*try --port 0 or another port"):
                await taken.start()
        finally:
            host.close()

    asyncio.run(main())


def test_an_mcap_file_that_cannot_be_written_is_one_sentence(tmp_path: Path) -> None:
    async def main() -> None:
        with pytest.raises(ConfigError, match="cannot write"):
            FoxgloveHost(FoxgloveSettings(port=0, mcap=str(tmp_path / "no" / "such" / "dir" / "view.mcap")))

    asyncio.run(main())


def test_subscriptions_go_to_the_watch_and_the_view_hears_of_each_change() -> None:
    async def main() -> None:
        host = FoxgloveHost(FoxgloveSettings(port=0))
        try:
            viewer = Viewer()
            host.viewer = viewer  # type: ignore[assignment]
            host.client_subscribed(1, "/pose", True)
            host.client_subscribed(2, "/pose", True)
            assert viewer.subscribed_to == ["/pose", "/pose"] and viewer.changes == 1, "the first subscriber changes what is watched"
            assert viewer.watch.needed() == {"robot/pose"}
            host.client_subscribed(1, "/pose", False)
            host.client_subscribed(2, "/pose", False)
            assert viewer.changes == 2 and viewer.watch.needed() == set()
            host.status(None, StatusLevel.INFO, "to every client")  # no client through the front: the SDK's broadcast
            host.answer(99, b"{}", None)  # a call nobody waits for: nothing happens
        finally:
            host.close()

    asyncio.run(main())
