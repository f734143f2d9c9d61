"""SIGINT/SIGTERM as a stop request, for an asyncio service or a thread-based tool."""

from __future__ import annotations

import asyncio
import signal
import threading

STOP_SIGNALS = (signal.SIGINT, signal.SIGTERM)


def stop_on_signals() -> threading.Event:
    """An event set by SIGINT or SIGTERM (call from the main thread; wait on it with a timeout).

    Python runs a signal's handler on the main thread, and only while that thread runs Python: a signal the kernel
    delivers to another thread (one of Zenoh's) waits until the main thread wakes. ``stop.wait()`` without a timeout may
    never wake; ``while not stop.wait(0.2)`` does.
    """
    stop = threading.Event()

    def on_signal(*_: object) -> None:
        # Not stop.set() here: the handler runs on the main thread, which may be inside
        # stop.wait() holding the event's lock at that instant; set() would then wait for
        # it forever. A thread sets it as soon as the main thread lets go.
        threading.Thread(target=stop.set, name="stop-signal", daemon=True).start()

    for sig in STOP_SIGNALS:
        signal.signal(sig, on_signal)
    return stop


def loop_stop_on_signals() -> asyncio.Event:
    """An asyncio event set by SIGINT or SIGTERM (call inside the running loop)."""
    stop = asyncio.Event()
    loop = asyncio.get_running_loop()
    for sig in STOP_SIGNALS:
        loop.add_signal_handler(sig, stop.set)
    return stop
