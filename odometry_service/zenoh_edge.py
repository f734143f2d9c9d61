"""Zenoh edge of the odometry service: declarations, and a queue between Zenoh's threads and ours."""

from __future__ import annotations

import queue
import threading
from typing import Any

import zenoh

from schemas import ErrorReport, PayloadError, Pose, encode, to_bytes

from .service import OdometryService

JSON = zenoh.Encoding.APPLICATION_JSON


class OdometryZenoh:
    """Publishes poses and errors; feeds impulses, pose queries and resets to a service, on one thread."""

    def __init__(self, session: zenoh.Session, prefix: str) -> None:
        self.session = session
        self.prefix = prefix
        self.inbox: queue.SimpleQueue[tuple[str, Any]] = queue.SimpleQueue()
        self._pose = session.declare_publisher(f"{prefix}/pose", encoding=JSON, express=True)  # no batching: latency
        self._errors = session.declare_publisher(f"{prefix}/errors", encoding=JSON)
        self._entities: list[Any] = [self._pose, self._errors]

    # OdometryOutput
    def pose(self, message: Pose) -> None:
        self._pose.put(encode(message))

    def error(self, message: ErrorReport) -> None:
        self._errors.put(encode(message))

    def attach(self) -> None:
        inbox = self.inbox

        def on_sample(sample: zenoh.Sample) -> None:
            try:
                inbox.put(("impulses", to_bytes(sample.payload)))
            except Exception:
                inbox.put(("impulses", b""))

        self._entities += [
            self.session.declare_subscriber(f"{self.prefix}/wheels/impulses", on_sample),
            self.session.declare_queryable(f"{self.prefix}/pose", lambda q: inbox.put(("pose", q))),
            self.session.declare_queryable(f"{self.prefix}/odometry/reset", lambda q: inbox.put(("reset", q))),
            self.session.liveliness().declare_token(f"{self.prefix}/alive/odometry"),
        ]

    def serve(self, service: OdometryService, stop: threading.Event, health_period: float = 1.0) -> None:
        """Drain the inbox until ``stop`` is set (polled every 100 ms)."""
        next_flush = service.clock() + health_period
        while not stop.is_set():
            try:
                kind, item = self.inbox.get(timeout=0.1)
            except queue.Empty:
                kind, item = "", None
            if kind == "impulses":
                service.on_impulses(item)
            elif kind == "pose":
                with item:
                    item.reply(f"{self.prefix}/pose", encode(service.latest()), encoding=JSON)
            elif kind == "reset":
                self._answer_reset(service, item)
            if service.clock() >= next_flush:
                service.flush_suppressed()
                next_flush = service.clock() + health_period

    def _answer_reset(self, service: OdometryService, query: zenoh.Query) -> None:
        with query:
            payload = None if query.payload is None else to_bytes(query.payload)
            try:
                pose = service.on_reset(payload)
            except PayloadError as exc:
                service.reject(f"{self.prefix}/odometry/reset", str(exc), exc.excerpt)
                query.reply_err(str(exc).encode())
                return
            query.reply(f"{self.prefix}/odometry/reset", encode(pose), encoding=JSON)

    def close(self) -> None:
        for entity in reversed(self._entities):
            try:
                entity.undeclare()
            except Exception:
                pass
        self._entities.clear()
