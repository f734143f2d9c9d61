"""Calibration of the odometry's constants, pure numpy (docs/commands/calibrate.md).

UMBmark in closed form in the start frame (x along the first side, y to the left), and a Levenberg-Marquardt
fit against a reference path, each evaluation one :func:`.batch.integrate` pass over one replay's travels.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
from numpy.typing import NDArray

from .batch import integrate
from .errors import OdometryError

F = NDArray[np.float64]

#: Metres of path error that weigh as much as one radian of heading error in the fit.
YAW_WEIGHT_M = 0.5


class CalibrationError(OdometryError):
    """The recordings cannot calibrate anything; the text says what is missing."""


@dataclass(frozen=True, slots=True)
class Constants:
    impulses_left: float
    impulses_right: float
    wheel_separation: float

    def relative_to(self, other: "Constants") -> tuple[float, float, float]:
        """Relative differences (self / other - 1) of the three constants."""
        return (
            self.impulses_left / other.impulses_left - 1.0,
            self.impulses_right / other.impulses_right - 1.0,
            self.wheel_separation / other.wheel_separation - 1.0,
        )


@dataclass(frozen=True, slots=True)
class UmbmarkResult:
    alpha: float  # rad, turn error per 90 degree corner (wheelbase)
    beta: float  # rad, heading change per straight side (unequal wheels)
    e_d: float  # right over left wheel diameter
    e_b: float  # actual over nominal wheelbase
    constants: Constants
    e_max_syst: float  # m, the larger distance of the two end points from the start


def umbmark(cw_end: tuple[float, float], ccw_end: tuple[float, float], side: float, used: Constants) -> UmbmarkResult:
    """Closed-form corrections from the true end points (start frame) of squares of ``side`` driven with ``used``."""
    if not side > 0:
        raise CalibrationError(f"the square's side must be positive, got {side}")
    y_cw, y_ccw = cw_end[1], ccw_end[1]
    alpha = (y_cw - y_ccw) / (-4.0 * side)
    beta = (y_cw + y_ccw) / (-4.0 * side)
    b = used.wheel_separation
    if abs(beta) < 1e-12:
        e_d = 1.0
    else:
        radius = (side / 2.0) / math.sin(beta / 2.0)
        e_d = (radius + b / 2.0) / (radius - b / 2.0)
    e_b = (math.pi / 2.0) / (math.pi / 2.0 - alpha)
    if not (0.5 < e_d < 2.0 and 0.5 < e_b < 2.0):
        raise CalibrationError(
            f"UMBmark gives implausible corrections (E_d {e_d:.3f}, E_b {e_b:.3f}): are the end points in metres, in the start frame?"
        )
    # distance per impulse of each wheel times c_L, c_R; their mean is kept (UMBmark cannot see it)
    c_left = 2.0 / (e_d + 1.0)
    c_right = 2.0 / (1.0 / e_d + 1.0)
    constants = Constants(used.impulses_left / c_left, used.impulses_right / c_right, used.wheel_separation * e_b)
    e_max = max(math.hypot(*cw_end), math.hypot(*ccw_end))
    return UmbmarkResult(alpha, beta, e_d, e_b, constants, e_max)


def centre_of_gravity(points: list[tuple[float, float]]) -> tuple[float, float]:
    if not points:
        raise CalibrationError("no end point given")
    return (sum(p[0] for p in points) / len(points), sum(p[1] for p in points) / len(points))


@dataclass
class Segment:
    """The wheels' travels per step under ``used`` constants, and the reference (odometry's start frame) at each step."""

    d_left: F
    d_right: F
    ref_x: F
    ref_y: F
    ref_yaw: F
    #: Seconds between each step and the one before (the first is 0), for the speed residuals; None: not known.
    dt: F | None = None


def align(ref_x: F, ref_y: F, ref_yaw: F) -> tuple[F, F, F]:
    """A reference path moved so that its first pose is the origin, heading along x."""
    c, s = math.cos(-ref_yaw[0]), math.sin(-ref_yaw[0])
    dx, dy = ref_x - ref_x[0], ref_y - ref_y[0]
    return c * dx - s * dy, s * dx + c * dy, ref_yaw - ref_yaw[0]


def _residuals(theta: F, segments: list[Segment]) -> F:
    scale_left, scale_right, separation = theta
    out: list[F] = []
    for seg in segments:
        x, y, yaw = integrate(seg.d_left * scale_left, seg.d_right * scale_right, separation)
        out += [x - seg.ref_x, y - seg.ref_y, YAW_WEIGHT_M * (yaw - seg.ref_yaw)]
    return np.concatenate(out)


@dataclass(frozen=True, slots=True)
class FitResult:
    constants: Constants
    rms_before: float  # m (yaw weighted in), over every step
    rms_after: float
    evaluations: int
    iterations: int


def fit_trajectory(segments: list[Segment], used: Constants, max_iterations: int = 50) -> FitResult:
    """Least-squares impulses per metre (both wheels) and separation; ``used`` are the constants of the travels."""
    if not segments or sum(len(s.d_left) for s in segments) < 10:
        raise CalibrationError("too few samples to fit (fewer than 10 steps with a reference)")
    travel = sum(float(np.sum(np.abs(s.d_left) + np.abs(s.d_right))) for s in segments) / 2.0
    ref_motion = max(float(np.ptp(np.hypot(s.ref_x, s.ref_y))) for s in segments)
    if ref_motion < 0.05:
        raise CalibrationError(
            f"the reference never moves (it spans {1000 * ref_motion:.0f} mm): is it the right channel, was it recorded?"
        )
    if travel < 0.1:
        raise CalibrationError(f"the wheels hardly moved ({travel:.3f} m): nothing to fit")
    turned = max(float(np.ptp(np.cumsum(s.d_right - s.d_left))) / used.wheel_separation for s in segments)
    if turned < math.radians(30):
        raise CalibrationError(
            "the recording hardly turns: the wheel separation cannot be fitted (drive squares: blackmetal square --both)"
        )
    theta = np.array([1.0, 1.0, used.wheel_separation])
    r = _residuals(theta, segments)
    cost = float(r @ r)
    n = len(r)
    rms_before = math.sqrt(cost / n)
    lam = 1e-3
    evaluations = 1
    iterations = 0
    converged = False
    steps = np.array([1e-6, 1e-6, 1e-6 * used.wheel_separation])
    for iterations in range(1, max_iterations + 1):  # noqa: B007 - reported
        jac = np.empty((n, 3))
        for i in range(3):
            t = theta.copy()
            t[i] += steps[i]
            jac[:, i] = (_residuals(t, segments) - r) / steps[i]
        evaluations += 3
        a = jac.T @ jac
        g = jac.T @ r
        improved = False
        while lam < 1e12:
            delta = np.linalg.solve(a + lam * np.diag(np.diag(a)), -g)
            candidate = theta + delta
            r_new = _residuals(candidate, segments)
            evaluations += 1
            cost_new = float(r_new @ r_new)
            if cost_new < cost:
                theta, r, lam, improved = candidate, r_new, max(lam / 10.0, 1e-12), True
                converged = bool(cost - cost_new <= 1e-12 * cost or np.all(np.abs(delta) <= 1e-10 * np.abs(theta)))
                cost = cost_new
                break
            lam *= 10.0
        if not improved or converged:
            break
    scale_left, scale_right, separation = (float(v) for v in theta)
    if not (0.5 < scale_left < 2.0 and 0.5 < scale_right < 2.0 and 0.25 * used.wheel_separation < separation < 4 * used.wheel_separation):
        raise CalibrationError(
            f"the fit did not converge to plausible constants (scales {scale_left:.3f}, {scale_right:.3f}, separation {separation:.3f} m)"
        )
    constants = Constants(used.impulses_left / scale_left, used.impulses_right / scale_right, separation)
    return FitResult(constants, rms_before, math.sqrt(cost / n), evaluations, iterations)


@dataclass(frozen=True, slots=True)
class ResidualFigures:
    """How far odometry with some constants still is from the reference: root mean squares over every step."""

    steps: int
    path_m: float
    x_m: float
    y_m: float
    yaw_rad: float
    v_mps: float  # nan when no segment knows its time steps
    w_radps: float


def residual_figures(segments: list[Segment], constants: Constants, used: Constants) -> ResidualFigures:
    """The odometry with ``constants`` against the reference, step by step: position, heading and, where the time steps
    are known, speed and turn rate. What ``/odom``'s covariance is made of (``blackmetal ros2 --calibration``)."""
    scale_left, scale_right = used.impulses_left / constants.impulses_left, used.impulses_right / constants.impulses_right
    ex, ey, eyaw, ev, ew = [], [], [], [], []
    path = 0.0
    for seg in segments:
        d_left, d_right = seg.d_left * scale_left, seg.d_right * scale_right
        x, y, yaw = integrate(d_left, d_right, constants.wheel_separation)
        ex.append(x - seg.ref_x)
        ey.append(y - seg.ref_y)
        eyaw.append(yaw - seg.ref_yaw)
        path += float(np.sum(np.abs(d_left + d_right))) / 2.0
        if seg.dt is not None and len(seg.dt) > 1:
            ok = seg.dt[1:] > 0
            dt = seg.dt[1:][ok]
            heading = seg.ref_yaw[:-1][ok]
            ref_v = (np.diff(seg.ref_x)[ok] * np.cos(heading) + np.diff(seg.ref_y)[ok] * np.sin(heading)) / dt
            ref_w = np.diff(seg.ref_yaw)[ok] / dt
            odo_v = (d_left[1:][ok] + d_right[1:][ok]) / 2.0 / dt
            odo_w = (d_right[1:][ok] - d_left[1:][ok]) / constants.wheel_separation / dt
            ev.append(odo_v - ref_v)
            ew.append(odo_w - ref_w)

    def rms(parts: list[F]) -> float:
        values = np.concatenate(parts) if parts else np.empty(0)
        return math.sqrt(float(np.mean(values * values))) if values.size else math.nan

    return ResidualFigures(sum(len(s.d_left) for s in segments), path, rms(ex), rms(ey), rms(eyaw), rms(ev), rms(ew))


def closure_error(d_left: F, d_right: F, ref_x: F, ref_y: F, constants: Constants, used: Constants) -> float:
    """Distance between where the odometry (with ``constants``) and the reference end, both from the same start (m)."""
    x, y, _ = integrate(
        d_left * used.impulses_left / constants.impulses_left,
        d_right * used.impulses_right / constants.impulses_right,
        constants.wheel_separation,
    )
    return math.hypot(x[-1] - ref_x[-1], y[-1] - ref_y[-1])
