"""Calibration: UMBmark by hand, the trajectory fit on synthetic paths, bad recordings, and the whole loop on the simulator."""

from __future__ import annotations

import math
import re
import subprocess
import sys
import tomllib
from pathlib import Path
from typing import NamedTuple

import numpy as np
import pytest
from helpers import Child, free_port, start_robot, zenoh_connect_args

from blackmetal import robot_model as model
from blackmetal.bench.synth import square_legs, synth_log
from blackmetal.odometry_service.batch import integrate
from blackmetal.odometry_service.calibration import CalibrationError, Constants, Segment, align, fit_trajectory, umbmark
from blackmetal.recording.writer import McapRecording
from blackmetal.robot_model import arc_step
from blackmetal.schemas import Keys, encode, make_pose

NOMINAL = Constants(model.IMPULSES_PER_METER_LEFT, model.IMPULSES_PER_METER_RIGHT, model.WHEEL_SEPARATION)


def square_end(scale_left: float, scale_right: float, true_separation: float, side: float, clockwise: bool) -> tuple[float, float]:
    """Where a robot really ends that drives a square perfectly by nominal odometry (exact arcs, as UMBmark models it)."""
    x = y = yaw = 0.0
    turn = -math.pi / 2 if clockwise else math.pi / 2
    for _ in range(4):
        for d_left, d_right in ((side, side), (-turn * NOMINAL.wheel_separation / 2, turn * NOMINAL.wheel_separation / 2)):
            for _ in range(400):
                x, y, yaw = arc_step(x, y, yaw, d_left / 400 * scale_left, d_right / 400 * scale_right, true_separation)
    return x, y


def cli(*args: str) -> subprocess.CompletedProcess[str]:
    return subprocess.run([sys.executable, "-m", "blackmetal", *args], capture_output=True, text=True, timeout=300)


# ------------------------------------------------------------------ UMBmark
def test_umbmark_matches_the_papers_formulas_by_hand() -> None:
    side = 4.0
    cw, ccw = (0.10, -0.05), (0.10, 0.25)  # centres of gravity of measured end points, start frame
    # Borenstein & Feng 1996, with our start frame (x along the first side, y left):
    alpha = (cw[1] - ccw[1]) / (-4 * side)  # (-0.05 - 0.25) / -16 = 0.01875 rad
    beta = (cw[1] + ccw[1]) / (-4 * side)  # (0.20) / -16 = -0.0125 rad
    radius = (side / 2) / math.sin(beta / 2)  # about -320 m
    e_d = (radius + 0.25) / (radius - 0.25)
    e_b = (math.pi / 2) / (math.pi / 2 - alpha)
    assert alpha == pytest.approx(0.01875) and beta == pytest.approx(-0.0125)
    result = umbmark(cw, ccw, side, NOMINAL)
    assert (result.alpha, result.beta, result.e_d, result.e_b) == pytest.approx((alpha, beta, e_d, e_b), rel=1e-12)
    c_left, c_right = 2 / (e_d + 1), 2 / (1 / e_d + 1)
    assert result.constants.impulses_left == pytest.approx(NOMINAL.impulses_left / c_left)
    assert result.constants.impulses_right == pytest.approx(NOMINAL.impulses_right / c_right)
    assert result.constants.wheel_separation == pytest.approx(NOMINAL.wheel_separation * e_b)
    assert result.e_max_syst == pytest.approx(math.hypot(*ccw))


def test_umbmark_corrections_recover_the_robot_to_first_order() -> None:
    scale_left, separation = 1.015, 0.515  # the left wheel 1.5 % larger, the wheelbase 3 % wider
    side = 2.0
    cw, ccw = square_end(scale_left, 1.0, separation, side, True), square_end(scale_left, 1.0, separation, side, False)
    result = umbmark(cw, ccw, side, NOMINAL)
    assert result.e_d == pytest.approx(1.0 / scale_left, rel=3e-3)  # right over left diameter
    assert result.e_b == pytest.approx(separation / NOMINAL.wheel_separation, rel=3e-3)
    assert result.e_max_syst > 0.5


# ------------------------------------------------------------------ the trajectory fit
def synthetic_segment(scale_left: float, scale_right: float, separation: float, clockwise: bool) -> Segment:
    """Nominal wheel travels of a square, and the true path a robot with other wheels drew with them."""
    log = synth_log(square_legs(side=2.0, clockwise=clockwise), seed=3)
    left, right = model.Encoders().to_speeds(log.left.astype(float), log.right.astype(float))
    dt = np.diff(log.stamp, prepend=log.stamp[0])
    d_left, d_right = left * dt, right * dt
    x, y, yaw = integrate(d_left * scale_left, d_right * scale_right, separation)
    return Segment(d_left, d_right, *align(x, y, yaw))


def test_fit_recovers_the_constants() -> None:
    segments = [synthetic_segment(1.015, 0.99, 0.515, False), synthetic_segment(1.015, 0.99, 0.515, True)]
    fit = fit_trajectory(segments, NOMINAL)
    truth = Constants(NOMINAL.impulses_left / 1.015, NOMINAL.impulses_right / 0.99, 0.515)
    assert max(abs(v) for v in fit.constants.relative_to(truth)) < 1e-6
    assert fit.rms_before > 0.1 and fit.rms_after < 1e-6


def test_fit_refuses_a_reference_that_never_moves_and_a_path_that_never_turns() -> None:
    seg = synthetic_segment(1.0, 1.0, 0.5, False)
    still = Segment(seg.d_left, seg.d_right, np.zeros_like(seg.ref_x), np.zeros_like(seg.ref_x), np.zeros_like(seg.ref_x))
    with pytest.raises(CalibrationError, match="never moves"):
        fit_trajectory([still], NOMINAL)
    straight = Segment(np.full(100, 0.01), np.full(100, 0.01), np.cumsum(np.full(100, 0.01)), np.zeros(100), np.zeros(100))
    with pytest.raises(CalibrationError, match="hardly turns"):
        fit_trajectory([straight], NOMINAL)


# ------------------------------------------------------------------ bad recordings: a clear error, no file written
def write_recording(path: Path, impulses: bool = True, truth: str = "moving", clockwise: bool | None = None) -> None:
    keys = Keys()
    rec = McapRecording(path, keys)
    runs = [False, True] if clockwise is None else [clockwise]
    t0 = 1_795_000_000.0
    for clockwise_run in runs:
        log = synth_log(square_legs(side=1.0, clockwise=clockwise_run), seed=2, start=t0)
        if impulses:
            for seq, stamp, left, right in zip(log.seq, log.stamp, log.left, log.right, strict=True):
                rec.write(keys.impulses, b'{"seq":%d,"stamp":%r,"left":%d,"right":%d}' % (seq, float(stamp), left, right), int(stamp * 1e9))
        for stamp in np.arange(log.stamp[0], log.stamp[-1], 0.02):
            x = 0.0 if truth == "still" else float(stamp - t0)
            rec.write(keys.sim_truth, encode(make_pose(float(stamp), x, 0.0, 0.0)), int(stamp * 1e9))
        rec.metadata(
            "blackmetal.square",
            {
                "direction": "clockwise" if clockwise_run else "counter-clockwise",
                "size_m": "1.0",
                "start_ns": str(int(log.stamp[0] * 1e9)),
                "end_ns": str(int(log.stamp[-1] * 1e9)),
            },
        )
        t0 = float(log.stamp[-1]) + 1.0
    rec.close()


@pytest.mark.parametrize(
    ("kind", "args", "message"),
    [
        ("no impulses", [], r"holds no wheel impulses"),
        ("still reference", [], r"the reference never moves"),
        ("single square", ["--cw-end=0.01,0.02", "--ccw-end=0.01,-0.02"], r"UMBmark needs a clockwise and a counter-clockwise square"),
        ("one end point only", ["--cw-end=0.01,0.02"], r"needs both --cw-end and --ccw-end"),
    ],
)
def test_bad_recordings_end_in_one_sentence_and_write_nothing(tmp_path: Path, kind: str, args: list[str], message: str) -> None:
    path = tmp_path / "run.mcap"
    write_recording(
        path,
        impulses=kind != "no impulses",
        truth="still" if kind == "still reference" else "moving",
        clockwise=False if kind == "single square" else None,
    )
    out = tmp_path / "calibration.toml"
    proc = cli("calibrate", str(path), "-o", str(out), *args)
    assert proc.returncode == 2, proc.stdout + proc.stderr
    assert re.search(message, proc.stderr), proc.stderr
    assert proc.stderr.count("\n") == 1 and "Traceback" not in proc.stderr
    assert not out.exists()


# ------------------------------------------------------------------ the whole loop on the simulator
#: The squares' side (m). With these wheels, nominal odometry misses the truth at the end of a 0.3 m
#: square by about 17 mm clockwise and 43 mm counter-clockwise (square_end); a calibrated one by
#: about 0.1 mm. A larger square misses by more, but takes longer to drive in real time.
LOOP_SIDE = "0.3"
#: The gateways' command timeout (s): square approaches each corner at the distance left over it
#: (see square.approach_gain), so a short one makes the loop faster; 20 Hz commands keep it fed.
LOOP_CMD_TIMEOUT = "0.15"
CLOSURE = r"^{direction}: odometry closure .*\(dx ([-+\d.]+), dy ([-+\d.]+)\).*\n\s+truth\s+closure .*\(dx ([-+\d.]+), dy ([-+\d.]+)\).*\n\s+odometry error ([\d.]+) mm"


class Squares(NamedTuple):
    recordings: list[Path]
    closures: dict[str, float]  # direction: odometry against the truth at the end (m)
    odometry_end: dict[str, tuple[float, float]]  # direction: where the odometry ended, start frame (m)
    true_end: dict[str, tuple[float, float]]  # direction: where the robot truly ended, start frame (m)


def drive_squares(children: list[Child], tmp_path: Path, name: str, settings: list[str]) -> Squares:
    """Two simulated robots (left wheel 1.5 % large, wheelbase 0.515 m), each with a gateway and an odometry,
    drive a counter-clockwise and a clockwise square at the same time (`square --record`)."""
    robots = []
    for _ in ("counter-clockwise", "clockwise"):
        zport = free_port()
        processes = start_robot(
            children,
            zport,
            sim_args=("--left-wheel-scale", "1.015", "--wheel-separation", "0.515"),
            gateway_args=("--cmd-timeout", LOOP_CMD_TIMEOUT, *settings),
            odometry_args=tuple(settings),
        )
        robots.append((zport, processes))
    squares = Squares([], {}, {}, {})
    drivers = []
    for direction, (zport, _) in zip(("counter-clockwise", "clockwise"), robots, strict=True):
        recording = tmp_path / f"{name}-{direction}.mcap"
        turn = ["--clockwise"] if direction == "clockwise" else []
        command = [sys.executable, "-m", "blackmetal", "square", *turn, "--size", LOOP_SIDE, "--speed", "0.5", "--turn-rate", "2.0",
                   "--record", str(recording), *zenoh_connect_args(zport)]  # fmt: skip
        drivers.append((direction, subprocess.Popen(command, stdout=subprocess.PIPE, stderr=subprocess.STDOUT, text=True)))
        squares.recordings.append(recording)
    for direction, proc in drivers:
        out, _ = proc.communicate(timeout=300)
        assert proc.returncode == 0, out
        # UMBmark's closure error: where the robot truly ended against where its odometry believes it
        # ended. The truth's own closure also holds the square driver's stopping error, which grows on
        # a loaded machine and is no business of the odometry's constants.
        match = re.search(CLOSURE.format(direction=direction), out, re.M)
        assert match, out
        odo_x, odo_y, true_x, true_y, error = (float(v) / 1000 for v in match.groups())
        squares.closures[direction] = error
        squares.odometry_end[direction] = (odo_x, odo_y)
        squares.true_end[direction] = (true_x, true_y)
    for _, processes in robots:
        for child in reversed(processes):
            child.stop()
    return squares


@pytest.mark.integration
def test_calibrate_then_drive_again(children: list[Child], tmp_path: Path) -> None:
    before = drive_squares(children, tmp_path, "before", [])
    calibration = tmp_path / "calibration.toml"
    proc = cli("calibrate", *map(str, before.recordings), "-o", str(calibration))
    assert proc.returncode == 0, proc.stdout + proc.stderr
    fitted = tomllib.loads(calibration.read_text())
    truth = {
        "impulses_left": model.IMPULSES_PER_METER_LEFT / 1.015,
        "impulses_right": model.IMPULSES_PER_METER_RIGHT,
        "wheel_separation": 0.515,
    }
    for name, value in truth.items():
        assert fitted[name] == pytest.approx(value, rel=3e-3), (name, fitted[name], value)
    # UMBmark from the true ends, what a tape measures: calibrate subtracts the odometry's ends, which it
    # replays from the recordings, so its E_max,syst is the true ends less the odometry's, as square says
    cw, ccw = before.true_end["clockwise"], before.true_end["counter-clockwise"]
    umb = cli("calibrate", *map(str, before.recordings), f"--cw-end={cw[0]},{cw[1]}", f"--ccw-end={ccw[0]},{ccw[1]}")
    assert umb.returncode == 0, umb.stdout + umb.stderr
    e_max = max(math.dist(before.true_end[d], before.odometry_end[d]) for d in before.true_end)
    calibrate_e_max = float(re.search(r"E_max,syst ([\d.]+) mm", umb.stdout).group(1)) / 1000  # type: ignore[union-attr]
    assert calibrate_e_max == pytest.approx(e_max, abs=0.5e-3), umb.stdout
    e_d = float(re.search(r"E_d \(right/left diameter\) ([\d.]+)", umb.stdout).group(1))  # type: ignore[union-attr]
    print(umb.stdout)
    # UMBmark's first-order formulas on two 0.3 m squares read E_d 0.15-0.18 % low here (0.98342-0.98372
    # in three runs) and a loaded CI machine's corners moved it to 0.39 % once (0.98134): 0.6 % is the
    # method's accuracy on squares this short; the fit above holds the constants to 0.3 %
    assert e_d == pytest.approx(1 / 1.015, rel=6e-3), umb.stdout
    after = drive_squares(children, tmp_path, "after", ["--settings", str(calibration)])
    print(f"closure error against the truth before {before.closures}, after {after.closures}; UMBmark:\n{umb.stdout}")
    for direction in before.closures:
        assert after.closures[direction] * 10 <= before.closures[direction], (direction, before.closures, after.closures)
