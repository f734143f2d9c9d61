"""The odometry's asyncio host: inputs stamped with the clock, the core's timers run on the loop."""

from __future__ import annotations

import asyncio

from blackmetal.bench.synth import square_legs, synth_log
from blackmetal.odometry_service.host import OdometryHost
from blackmetal.schemas import encode
from unit.odometry_service.test_core import RecordingOdometryOutput, live, service


def test_the_host_stamps_inputs_and_runs_the_cores_timers_on_the_loop() -> None:
    async def scenario() -> RecordingOdometryOutput:
        svc, out = service()
        svc.reporter.summary_period = 0.02  # summaries come from the core's tick, not from a host timer
        host = OdometryHost(svc)
        stop = asyncio.Event()
        dropped = [0]
        running = asyncio.create_task(host.run(stop, dropped=lambda: dropped[0]))
        await asyncio.sleep(0)
        for msg in live(synth_log(square_legs(side=0.5), seed=1), pace=1e-3)[:20]:  # delivered at once: mono barely moves
            host.on_impulses(encode(msg))
        dropped[0] = 5  # the bounded input dropped five samples while these waited
        host.on_impulses(b"garbage")
        await asyncio.sleep(0.01)  # the core's tick reports them at once
        for _ in range(12):
            host.on_impulses(b"garbage")
        assert host.on_reset(None).x == 0.0
        for _ in range(200):  # a token comes back after 1/rate = 0.2 s; then the next tick summarises
            if any("were rate-limited" in e.reason for e in out.errors):
                break
            await asyncio.sleep(0.01)
        stop.set()
        await running
        return out

    out = asyncio.run(scenario())
    assert len(out.poses) == 20
    reasons = [e.reason for e in out.errors]
    assert any(r.startswith("5 impulse samples dropped") for r in reasons)
    assert any("were rate-limited" in r for r in reasons)
