"""The part of tf2's ``BufferCore`` (https://github.com/ros2/geometry2, ``tf2/src/buffer_core.cpp``,
``time_cache.cpp``) that a lookup of the latest transform uses, as free_fleet's ``Nav2TfHandler`` relies on it:
``set_transform`` into a time-ordered cache per child frame (10 s, pruned against the newest), and
``lookup_transform(target, source, Time())``: the latest time every link of the chain has
(``getLatestCommonTime``), each link interpolated there.
"""

from __future__ import annotations

import itertools
import math
import threading
from dataclasses import dataclass

Quat = tuple[float, float, float, float]
Vec = tuple[float, float, float]


class TfLookupError(Exception):
    """tf2's LookupException / ConnectivityException / ExtrapolationException: why the transform cannot be had."""


@dataclass
class _Stored:
    stamp: float
    parent: str
    translation: Vec
    rotation: Quat


def _qmul(a: Quat, b: Quat) -> Quat:
    ax, ay, az, aw = a
    bx, by, bz, bw = b
    return (
        aw * bx + ax * bw + ay * bz - az * by,
        aw * by - ax * bz + ay * bw + az * bx,
        aw * bz + ax * by - ay * bx + az * bw,
        aw * bw - ax * bx - ay * by - az * bz,
    )


def _rotate(q: Quat, v: Vec) -> Vec:
    x, y, z, _ = _qmul(_qmul(q, (v[0], v[1], v[2], 0.0)), (-q[0], -q[1], -q[2], q[3]))
    return (x, y, z)


def _slerp(a: Quat, b: Quat, ratio: float) -> Quat:
    dot = sum(p * q for p, q in zip(a, b, strict=True))
    if dot < 0:
        b, dot = (-b[0], -b[1], -b[2], -b[3]), -dot
    if dot > 0.9995:
        mixed = [p + ratio * (q - p) for p, q in zip(a, b, strict=True)]
    else:
        theta = math.acos(min(1.0, dot))
        sa, sb = math.sin((1 - ratio) * theta), math.sin(ratio * theta)
        mixed = [(sa * p + sb * q) / math.sin(theta) for p, q in zip(a, b, strict=True)]
    norm = math.sqrt(sum(c * c for c in mixed))
    return (mixed[0] / norm, mixed[1] / norm, mixed[2] / norm, mixed[3] / norm)


class TfBuffer:
    """tf2's BufferCore for non-static transforms: a time-ordered cache per child frame (10 s by default, the
    oldest pruned against the newest), parents per sample, and ``lookup(target, source)`` at time zero: the
    latest time every link of the chain has (``getLatestCommonTime``), each link interpolated there (linear
    translation, slerp rotation), an ExtrapolationException when a link's cache does not reach that time."""

    def __init__(self, cache_time: float = 10.0) -> None:
        self.cache_time = cache_time
        self._frames: dict[str, list[_Stored]] = {}
        self._lock = threading.Lock()

    def set_transform(self, parent: str, child: str, stamp: float, translation: Vec, rotation: Quat) -> bool:
        """``BufferCore::setTransform``: False (and nothing stored) for what tf2 refuses."""
        if not parent or not child or parent == child:
            return False
        if not all(math.isfinite(v) for v in (*translation, *rotation)):
            return False
        norm = math.sqrt(sum(c * c for c in rotation))
        if abs(norm - 1.0) > 10 * 1e-3:  # tf2's QUATERNION_NORMALIZATION_TOLERANCE is 10e-3
            return False
        rotation = (rotation[0] / norm, rotation[1] / norm, rotation[2] / norm, rotation[3] / norm)
        with self._lock:
            cache = self._frames.setdefault(child, [])
            if cache and stamp < cache[-1].stamp - self.cache_time:
                return False  # TF_OLD_DATA: older than the cache reaches
            position = len(cache)
            while position > 0 and cache[position - 1].stamp > stamp:
                position -= 1
            if position > 0 and cache[position - 1].stamp == stamp:
                cache[position - 1] = _Stored(stamp, parent, translation, rotation)
            else:
                cache.insert(position, _Stored(stamp, parent, translation, rotation))
            newest = cache[-1].stamp
            while cache and cache[0].stamp < newest - self.cache_time:
                cache.pop(0)
        return True

    def _at(self, frame: str, when: float) -> _Stored:
        cache = self._frames[frame]
        if when == 0.0:
            return cache[-1]
        if len(cache) == 1:
            if cache[0].stamp == when:
                return cache[0]
            raise TfLookupError(f"extrapolation: {frame} has one transform, at {cache[0].stamp:.3f}, asked at {when:.3f}")
        if when < cache[0].stamp:
            raise TfLookupError(f"extrapolation into the past: {frame}'s cache starts at {cache[0].stamp:.3f}, asked at {when:.3f}")
        if when > cache[-1].stamp:
            raise TfLookupError(f"extrapolation into the future: {frame}'s cache ends at {cache[-1].stamp:.3f}, asked at {when:.3f}")
        for older, newer in itertools.pairwise(cache):
            if older.stamp <= when <= newer.stamp:
                if newer.stamp == older.stamp or older.parent != newer.parent:
                    return newer
                ratio = (when - older.stamp) / (newer.stamp - older.stamp)
                translation = tuple(a + ratio * (b - a) for a, b in zip(older.translation, newer.translation, strict=True))
                return _Stored(when, newer.parent, translation, _slerp(older.rotation, newer.rotation, ratio))
        raise AssertionError("unreachable")

    def _chain(self, frame: str) -> list[str]:
        """The frames from ``frame`` up to its root, by the latest parents."""
        chain = [frame]
        while chain[-1] in self._frames and len(chain) < 100:
            chain.append(self._frames[chain[-1]][-1].parent)
        return chain

    def lookup(self, target: str, source: str) -> tuple[Vec, Quat, float]:
        """The pose of ``source`` in ``target`` at the latest common time: (translation, rotation, that time)."""
        with self._lock:
            if target == source:
                return (0.0, 0.0, 0.0), (0.0, 0.0, 0.0, 1.0), 0.0
            up_source, up_target = self._chain(source), self._chain(target)
            if source not in self._frames and target not in self._frames:
                raise TfLookupError(f'"{target}" passed to lookupTransform argument target_frame does not exist')
            common = next((f for f in up_source if f in up_target), None)
            if common is None:
                raise TfLookupError(f"{target} and {source} are not part of the same tree")
            links = up_source[: up_source.index(common)] + up_target[: up_target.index(common)]
            latest = [self._frames[f][-1].stamp for f in links]
            when = min((t for t in latest if t != 0.0), default=0.0)

            def to_common(chain: list[str]) -> tuple[Vec, Quat]:
                translation: Vec = (0.0, 0.0, 0.0)
                rotation: Quat = (0.0, 0.0, 0.0, 1.0)
                for frame in chain[: chain.index(common)]:  # child to parent: x_parent = R x_child + t
                    link = self._at(frame, when)
                    moved = _rotate(link.rotation, translation)
                    translation = (moved[0] + link.translation[0], moved[1] + link.translation[1], moved[2] + link.translation[2])
                    rotation = _qmul(link.rotation, rotation)
                return translation, rotation

            ts, qs = to_common(up_source)
            tt, qt = to_common(up_target)
            inverse: Quat = (-qt[0], -qt[1], -qt[2], qt[3])
            delta = _rotate(inverse, (ts[0] - tt[0], ts[1] - tt[1], ts[2] - tt[2]))
            return delta, _qmul(inverse, qs), when
