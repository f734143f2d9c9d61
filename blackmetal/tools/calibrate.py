"""``blackmetal calibrate RECORDING...``: the odometry's constants from recorded driving (UMBmark or a trajectory fit).

Two modes:

* trajectory (default): the recording holds a reference pose channel
  (``<prefix>/sim/truth``, or ``--reference KEY`` from motion capture); the
  left and right impulses per metre and the wheel separation are fitted by
  least squares of the replayed odometry against it along the whole path;
* UMBmark (``--cw-end DX,DY --ccw-end DX,DY``, repeatable): the true end
  points of the clockwise and counter-clockwise squares, measured in the
  start frame (x along the first side, y to the left), less where the
  recorded odometry ended them, give the wheel diameter ratio and the
  wheelbase in closed form (Borenstein and Feng 1996).

Recordings are MCAP files from ``blackmetal square --record`` (which marks
each square) or ``blackmetal record``, or JSON lines of impulses (one run
per file). ``-o calibration.toml`` writes the constants as a settings file
that ``blackmetal gateway``, ``blackmetal odometry`` and ``blackmetal up``
take with ``--settings``. The constants the recordings were driven with are
the pipeline options (``--settings`` of a previous calibration, for a second
round); they default to the nominal ones.
"""

from __future__ import annotations

import argparse
import math
import time
from dataclasses import dataclass
from pathlib import Path

import msgspec
import numpy as np

from blackmetal.odometry_service.batch import BatchResult
from blackmetal.odometry_service.calibration import (
    CalibrationError,
    Constants,
    ResidualFigures,
    Segment,
    align,
    centre_of_gravity,
    closure_error,
    fit_trajectory,
    residual_figures,
    umbmark,
)
from blackmetal.odometry_service.replay import read_log
from blackmetal.odometry_service.settings import PipelineSettings
from blackmetal.recording.reader import is_mcap, read_mcap
from blackmetal.robot_model import Residuals
from blackmetal.runtime.settings import add_setting_arguments, load_settings
from blackmetal.schemas import ConfigError, Keys, Pose

from .client import tool
from .replay import load_impulses


@dataclass
class Run:
    """One square (or one whole recording): where it is in the replay, which way it turns."""

    source: str
    start: int
    end: int  # exclusive
    direction: str  # "clockwise" or "counter-clockwise"
    side: float | None


@dataclass
class Recording:
    result: BatchResult
    runs: list[Run]
    reference: tuple[np.ndarray, np.ndarray, np.ndarray] | None  # x, y, yaw at each replayed step (aligned later), NaN outside


def parse_point(text: str) -> tuple[float, float]:
    try:
        dx, dy = (float(v) for v in text.split(","))
    except ValueError:
        raise ConfigError(f"an end point is DX,DY in metres, e.g. 0.012,-0.034; got {text!r}") from None
    if not (math.isfinite(dx) and math.isfinite(dy)):
        raise ConfigError(f"an end point must be finite numbers, got {text!r}")
    return dx, dy


def _direction(result: BatchResult, start: int, end: int) -> str:
    turned = float(result.yaw[end - 1] - (result.yaw[start - 1] if start else 0.0))
    return "counter-clockwise" if turned > 0 else "clockwise"


def _runs(path: str, result: BatchResult, metadata: list[tuple[str, dict[str, str]]]) -> list[Run]:
    spans = [m for name, m in metadata if name == "blackmetal.square"]
    stamps_ns = result.stamp * 1e9
    runs = []
    for span in spans:
        try:
            start_ns, end_ns = float(span["start_ns"]), float(span["end_ns"])
            side = float(span["size_m"])
        except (KeyError, ValueError):
            continue
        start, end = int(np.searchsorted(stamps_ns, start_ns)), int(np.searchsorted(stamps_ns, end_ns))
        if end - start > 10:
            runs.append(Run(path, start, end, span.get("direction") or _direction(result, start, end), side))
    if not runs and len(result) > 10:
        runs.append(Run(path, 0, len(result), _direction(result, 0, len(result)), None))
    return runs


def _reference(path: str, key: str, result: BatchResult) -> tuple[np.ndarray, np.ndarray, np.ndarray] | None:
    if (channel := read_mcap(path, [key]).channels.get(key)) is None or not channel.payloads:
        return None
    decoder = msgspec.json.Decoder(Pose)
    poses = []
    for payload in channel.payloads:
        try:
            poses.append(decoder.decode(payload))
        except (msgspec.DecodeError, msgspec.ValidationError):
            continue  # a recording is evidence: bad payloads are in it, and skipped here
    if len(poses) < 2:
        return None
    poses.sort(key=lambda pose: pose.stamp)  # stable: poses of one stamp keep their order
    t, x, y, yaw = (np.array([getattr(pose, name) for pose in poses]) for name in ("stamp", "x", "y", "yaw"))
    inside = (result.stamp >= t[0]) & (result.stamp <= t[-1])
    x, y, yaw = (np.where(inside, np.interp(result.stamp, t, v), np.nan) for v in (x, y, np.unwrap(yaw)))
    return x, y, yaw


def load(path: str, settings: PipelineSettings, prefix: str | None, reference: str | None) -> Recording:
    data, _ = load_impulses(path, prefix)
    if not data.strip():
        raise CalibrationError(f"{path} holds no wheel impulses ({'no <prefix>/wheels/impulses channel' if is_mcap(path) else 'empty'})")
    result = read_log(data).replay(settings.params())
    if len(result) < 10:
        raise CalibrationError(f"{path} holds only {len(result)} usable impulse samples")
    metadata = read_mcap(path, []).metadata if is_mcap(path) else []
    ref = _reference(path, reference, result) if reference and is_mcap(path) else None
    return Recording(result, _runs(path, result, metadata), ref)


def _segment(rec: Recording, start: int, end: int) -> Segment | None:
    """The steps start..end that have a reference, with the reference moved into the odometry's frame at ``start``."""
    assert rec.reference is not None and rec.result.d_left is not None and rec.result.d_right is not None
    x, y, yaw = (v[start:end] for v in rec.reference)
    ok = np.isfinite(x)
    if ok.sum() < 10:
        return None
    first = int(np.argmax(ok))
    last = len(ok) - int(np.argmax(ok[::-1]))
    sl = slice(first, last)
    d_left, d_right = rec.result.d_left[start:end][sl].copy(), rec.result.d_right[start:end][sl].copy()
    d_left[0] = d_right[0] = 0.0  # the odometry starts at the reference's first pose
    dt = np.concatenate([[0.0], np.diff(rec.result.stamp[start:end][sl])])
    return Segment(d_left, d_right, *align(x[sl], y[sl], yaw[sl]), dt)


def write_toml(path: str, constants: Constants, note: str, residuals: Residuals | None = None) -> None:
    measured = ""
    if residuals is not None:
        measured = (
            "# The calibrated odometry against the reference, root mean squares over every step (m, rad, m/s, rad/s):\n"
            f"# blackmetal ros2 --calibration {Path(path).name} makes /odom's covariance of them. Comments, so that\n"
            "# every service takes this file as its settings.\n" + "".join(line + "\n" for line in residuals.lines())
        )
    text = (
        f"# {note}\n# For blackmetal gateway, blackmetal odometry and blackmetal up: --settings {Path(path).name}\n{measured}"
        f"wheel_separation = {constants.wheel_separation:.6f}\nimpulses_left = {constants.impulses_left:.4f}\n"
        f"impulses_right = {constants.impulses_right:.4f}\n"
    )
    try:
        Path(path).write_text(text)
    except OSError as exc:
        raise ConfigError(f"cannot write {path}: {exc.strerror}") from None


def _show(name: str, c: Constants, used: Constants) -> str:
    dl, dr, ds = c.relative_to(used)
    return (
        f"{name}: impulses_left {c.impulses_left:.3f} ({100 * dl:+.2f} %), impulses_right {c.impulses_right:.3f} ({100 * dr:+.2f} %), "
        f"wheel_separation {c.wheel_separation:.5f} m ({100 * ds:+.2f} %)"
    )


def as_residuals(figures: ResidualFigures) -> Residuals | None:
    """The file's residuals; None when the speeds could not be compared (no time steps)."""
    if not (math.isfinite(figures.v_mps) and math.isfinite(figures.w_radps)):
        return None
    return Residuals(**{name: getattr(figures, name) for name in Residuals.__dataclass_fields__})


def trajectory(recordings: list[Recording], used: Constants, reference: str) -> tuple[Constants, list[str], Residuals | None]:
    referenced = [rec for rec in recordings if rec.reference is not None]
    segments = [seg for rec in referenced if (seg := _segment(rec, 0, len(rec.result))) is not None]
    runs = [(run, seg) for rec in referenced for run in rec.runs if (seg := _segment(rec, run.start, run.end)) is not None]
    if not segments:
        raise CalibrationError(
            f"no recording holds the reference {reference} over its impulses: record the simulator's truth "
            "(blackmetal square --record), name a motion-capture channel with --reference, or measure end points for UMBmark (--cw-end/--ccw-end)"
        )
    started = time.perf_counter()
    fit = fit_trajectory(segments, used)
    took = time.perf_counter() - started
    lines = [
        f"trajectory fit against {reference}: {sum(len(s.d_left) for s in segments)} steps, {fit.iterations} iterations, "
        f"{fit.evaluations} replays of the path in {took:.2f} s",
        _show("used  ", used, used),
        _show("fitted", fit.constants, used),
        f"path error (rms, heading weighted {0.5} m/rad): {1000 * fit.rms_before:.1f} mm before, {1000 * fit.rms_after:.1f} mm after",
    ]
    figures = residual_figures(segments, fit.constants, used)
    lines.append(
        f"residuals after the fit over {figures.path_m:.2f} m ({figures.steps} steps, rms): x {1000 * figures.x_m:.1f} mm, "
        f"y {1000 * figures.y_m:.1f} mm, yaw {math.degrees(figures.yaw_rad):.2f} deg, "
        f"v {1000 * figures.v_mps:.1f} mm/s, w {math.degrees(figures.w_radps):.2f} deg/s"
    )
    for run, seg in runs:
        before = closure_error(seg.d_left, seg.d_right, seg.ref_x, seg.ref_y, used, used)
        after = closure_error(seg.d_left, seg.d_right, seg.ref_x, seg.ref_y, fit.constants, used)
        lines.append(
            f"  {run.direction} run of {Path(run.source).name}: odometry vs reference at its end {1000 * before:.1f} mm before, {1000 * after:.1f} mm after"
        )
    return fit.constants, lines, as_residuals(figures)


def odometry_end(rec: Recording, run: Run) -> tuple[float, float]:
    """Where the replayed odometry ended ``run``, in the robot's frame at its start (x ahead, y to the left), m."""
    r = rec.result
    first, last = run.start, run.end - 1
    dx, dy = float(r.x[last] - r.x[first]), float(r.y[last] - r.y[first])
    c, s = math.cos(float(r.yaw[first])), math.sin(float(r.yaw[first]))
    return c * dx + s * dy, -s * dx + c * dy


def umbmark_mode(
    recordings: list[Recording], used: Constants, cw: list[tuple[float, float]], ccw: list[tuple[float, float]], side: float | None
) -> tuple[Constants, list[str]]:
    runs = [run for rec in recordings for run in rec.runs]
    directions = {run.direction for run in runs}
    if directions != {"clockwise", "counter-clockwise"}:
        only = ", ".join(sorted(directions)) or "no square"
        raise CalibrationError(
            f"UMBmark needs a clockwise and a counter-clockwise square; the recordings hold {only} (drive blackmetal square --both --record FILE)"
        )
    sides = {run.side for run in runs if run.side is not None}
    if side is None:
        if len(sides) != 1:
            raise CalibrationError("give the squares' side with --size (the recordings do not say it, or say several)")
        side = sides.pop()
    # the return error is the true end minus the odometry's (square.umbmark_figure), which the recordings say
    measured = {"clockwise": centre_of_gravity(cw), "counter-clockwise": centre_of_gravity(ccw)}
    believed = {
        d: centre_of_gravity([odometry_end(rec, run) for rec in recordings for run in rec.runs if run.direction == d]) for d in measured
    }
    error = {d: (measured[d][0] - believed[d][0], measured[d][1] - believed[d][1]) for d in measured}
    result = umbmark(error["clockwise"], error["counter-clockwise"], side, used)
    lines = [f"UMBmark, {side:g} m squares, {len(cw)} clockwise and {len(ccw)} counter-clockwise end points"]
    for d in measured:
        lines.append(
            f"  {d}: measured end ({measured[d][0]:+.4f}, {measured[d][1]:+.4f}) m, the odometry's ({believed[d][0]:+.4f}, {believed[d][1]:+.4f}) m, "
            f"return error ({error[d][0]:+.4f}, {error[d][1]:+.4f}) m"
        )
    lines += [
        f"  E_max,syst {1000 * result.e_max_syst:.1f} mm; alpha {math.degrees(result.alpha):+.3f} deg, beta {math.degrees(result.beta):+.3f} deg",
        f"  E_d (right/left diameter) {result.e_d:.5f}, E_b (wheelbase) {result.e_b:.5f}",
        _show("used    ", used, used),
        _show("corrected", result.constants, used),
        "  (UMBmark keeps the mean wheel size; measure a straight run against a tape to correct it)",
    ]
    return result.constants, lines


@tool("calibrate")
def run(args: argparse.Namespace) -> int:
    settings = load_settings(PipelineSettings, args)
    used = Constants(settings.impulses_left, settings.impulses_right, settings.wheel_separation)
    cw = [parse_point(p) for p in args.cw_end or []]
    ccw = [parse_point(p) for p in args.ccw_end or []]
    if bool(cw) != bool(ccw):
        raise ConfigError("UMBmark needs both --cw-end and --ccw-end (the measured end points of both squares)")
    if args.size is not None and not args.size > 0:
        raise ConfigError(f"--size must be positive, got {args.size}")
    prefix = args.prefix
    reference = args.reference or f"{Keys(prefix or 'robot').sim_truth}"
    recordings = [load(path, settings, prefix, None if cw else reference) for path in args.recordings]
    residuals = None  # UMBmark measures two end points, not the path: no residuals
    if cw:
        constants, lines = umbmark_mode(recordings, used, cw, ccw, args.size)
        how = "UMBmark"
    else:
        constants, lines, residuals = trajectory(recordings, used, reference)
        how = f"trajectory fit against {reference}"
    for line in lines:
        print(line, flush=True)
    if args.output:
        names = ", ".join(Path(p).name for p in args.recordings)
        write_toml(args.output, constants, f"blackmetal calibrate, {time.strftime('%Y-%m-%d %H:%M')}, {how}, from {names}", residuals)
        print(f"wrote {args.output}: use it with --settings {args.output}", flush=True)
    return 0


def build_parser(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("recordings", nargs="+", metavar="RECORDING", help="MCAP recordings or JSON-lines impulse logs")
    parser.add_argument("-o", "--output", metavar="FILE.toml", help="write the constants as a settings file")
    parser.add_argument("--reference", metavar="KEY", help="reference pose channel for the trajectory fit (default <prefix>/sim/truth)")
    parser.add_argument(
        "--cw-end",
        action="append",
        metavar="DX,DY",
        help="UMBmark: measured end of a clockwise square, m, start frame (repeatable; write --cw-end=DX,DY when DX is negative)",
    )
    parser.add_argument(
        "--ccw-end", action="append", metavar="DX,DY", help="UMBmark: measured end of a counter-clockwise square (repeatable)"
    )
    parser.add_argument("--size", type=float, metavar="M", help="UMBmark: the squares' side (default: as recorded)")
    parser.add_argument("--prefix", help="the robot's prefix in the recordings (default: the one they hold)")
    add_setting_arguments(parser, PipelineSettings)
