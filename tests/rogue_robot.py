"""A misbehaving robot for end-to-end safety tests, written here, independent of the simulator.

It speaks the wire protocol with its own minimal parser (requests are plain
JSON), keeps what it *accepted* (a velocity answered RECIEVE_OK), reports
wheel speeds from that, and misbehaves on demand: FULL_BUFFER bursts,
floods on either port, late replies, closing every connection at once.
Every command's arrival is stamped, so tests measure what reached the
robot and when.
"""

from __future__ import annotations

import json
import selectors
import socket
import threading
import time
from dataclasses import dataclass, field

IMPULSES_LEFT, IMPULSES_RIGHT = 1012.53636364, 1053.67588345
OK, FULL = b'{"status":"RECIEVE_OK"}', b'{"status":"FULL_BUFFER"}'


@dataclass
class Behaviour:
    #: Answer FULL_BUFFER (and drop the command) to every command received before this monotonic time.
    full_buffer_until: float = 0.0
    #: Answer FULL_BUFFER to everything, always.
    always_full: bool = False
    #: When a zero velocity arrives while moving, answer FULL_BUFFER for this long (s) from then on.
    full_buffer_on_stop: float = 0.0
    #: Delay every reply by this long (s).
    reply_delay: float = 0.0
    #: Flood the log port / the control port with this byte pattern, as fast as possible.
    log_flood: bytes = b""
    control_flood: bytes = b""
    #: Close every new control connection at once.
    close_at_once: bool = False
    #: Send no log reports at all.
    log_silent: bool = False


@dataclass
class RogueRobot:
    behaviour: Behaviour = field(default_factory=Behaviour)
    control_port: int = 0
    log_port: int = 0
    speed: tuple[float, float] = (0.0, 0.0)  # accepted (left, right) rim speeds, m/s
    arrivals: list[tuple[float, int, tuple[float, float] | None]] = field(default_factory=list)  # (time, command, wheels)
    connections: int = 0
    lock: threading.Lock = field(default_factory=threading.Lock)

    def start(self) -> "RogueRobot":
        self._stop = threading.Event()
        self._sel = selectors.DefaultSelector()
        self._servers = []
        for kind in ("control", "log"):
            server = socket.socket()
            server.setsockopt(socket.SOL_SOCKET, socket.SO_REUSEADDR, 1)
            server.bind(("127.0.0.1", 0))
            server.listen(16)
            server.setblocking(False)
            setattr(self, f"{kind}_port", server.getsockname()[1])
            self._sel.register(server, selectors.EVENT_READ, ("accept", kind))
            self._servers.append(server)
        self._log_clients: list[socket.socket] = []
        self._control: socket.socket | None = None
        self._delayed: list[tuple[float, socket.socket, bytes]] = []
        self._thread = threading.Thread(target=self._run, name="rogue-robot", daemon=True)
        self._thread.start()
        return self

    def stop(self) -> None:
        self._stop.set()
        self._thread.join(5)
        for sock in [*self._servers, *self._log_clients, *([self._control] if self._control else [])]:
            sock.close()

    # ------------------------------------------------------------------ queries for tests

    def commands(self, code: int, since: float = 0.0) -> list[tuple[float, tuple[float, float] | None]]:
        with self.lock:
            return [(t, w) for t, c, w in self.arrivals if c == code and t >= since]

    def moving(self) -> bool:
        return any(abs(v) > 1e-9 for v in self.speed)

    # ------------------------------------------------------------------ the robot

    def _run(self) -> None:
        buffers: dict[socket.socket, bytes] = {}
        next_log = time.monotonic()
        while not self._stop.is_set():
            flooding = self.behaviour.log_flood or self.behaviour.control_flood
            for key, _ in self._sel.select(0 if flooding else 0.002):
                kind, port = key.data
                sock: socket.socket = key.fileobj  # type: ignore[assignment]
                if kind == "accept":
                    conn, _ = sock.accept()
                    conn.setsockopt(socket.IPPROTO_TCP, socket.TCP_NODELAY, 1)
                    if port == "log":
                        conn.setblocking(False)
                        self._log_clients.append(conn)
                        continue
                    self.connections += 1
                    if self.behaviour.close_at_once:
                        conn.close()
                        continue
                    if self._control is not None:  # a new control client takes over
                        self._sel.unregister(self._control)
                        self._control.close()
                    self._control = conn
                    buffers[conn] = b""
                    self._sel.register(conn, selectors.EVENT_READ, ("control", None))
                    continue
                try:
                    data = sock.recv(65536)
                except OSError:
                    data = b""
                if not data:
                    self._sel.unregister(sock)
                    sock.close()
                    if sock is self._control:
                        self._control = None
                    continue
                buffers[sock] += data
                while b"}" in buffers[sock]:
                    frame, _, buffers[sock] = buffers[sock].partition(b"}")
                    self._handle(sock, frame[frame.find(b"{") :] + b"}")
            now = time.monotonic()
            while self._delayed and self._delayed[0][0] <= now:
                _, sock, reply = self._delayed.pop(0)
                self._send(sock, reply)
            if self.behaviour.control_flood and self._control is not None:
                self._send(self._control, self.behaviour.control_flood * 1024)
            for client in list(self._log_clients):
                if self.behaviour.log_flood:
                    self._send(client, self.behaviour.log_flood * 1024)
                elif now >= next_log and not self.behaviour.log_silent:
                    self._send(client, b'{"state":1,"direction":1}')
            if now >= next_log:
                next_log = now + 1.0

    def _send(self, sock: socket.socket, data: bytes) -> None:
        try:
            sock.setblocking(False)
            sock.send(data)
        except (BlockingIOError, OSError):
            pass  # a full socket buffer drops the rest, as a flooding robot would

    def _handle(self, sock: socket.socket, frame: bytes) -> None:
        try:
            request = json.loads(frame)
            code = int(request["Command"])
        except (ValueError, KeyError, TypeError):
            return
        now = time.monotonic()
        wheels = None
        if code == 3:
            wheels = (float(request["LeftWheelSpeed"]), float(request["RightWheelSpeed"]))
        with self.lock:
            self.arrivals.append((now, code, wheels))
        b = self.behaviour
        if code == 3 and wheels == (0.0, 0.0) and self.moving() and b.full_buffer_on_stop:
            b.full_buffer_until = now + b.full_buffer_on_stop
            b.full_buffer_on_stop = 0.0
        if b.always_full or now < b.full_buffer_until:
            reply = FULL
        else:
            reply = OK
            if code == 3 and wheels is not None:
                self.speed = wheels
            elif code in (1, 2):
                self.speed = (0.0, 0.0)
            elif code == 6:
                left = round(self.speed[0] * IMPULSES_LEFT)
                right = -round(self.speed[1] * IMPULSES_RIGHT)
                reply += b'{"LeftWheelSpeed"=%d "RightWheelSpeed"=%d}' % (left, right)
        if b.reply_delay:
            self._delayed.append((now + b.reply_delay, sock, reply))
        else:
            self._send(sock, reply)
