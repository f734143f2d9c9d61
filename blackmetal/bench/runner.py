"""The bench's runner: what a figure is, how any figure is measured, skipped or failed, and the table's layout.

It knows no figure by name: each family module declares its figures as :class:`Figure`.
"""

from __future__ import annotations

import statistics
import subprocess
import traceback
from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path
from typing import Any, TypeVar

from blackmetal.runtime.harness import ChildFailed
from blackmetal.schemas import BlackmetalError, MissingExtra, require_extra

from . import children

#: The modules each optional extra brings, as the commands that need them check them.
EXTRA_MODULES: dict[str, tuple[str, ...]] = {"ros2": ("rosbags", "xxhash"), "record": ("mcap",)}

T = TypeVar("T")
Row = tuple[str, str, str, str]
Result = dict[str, Any]


def missing_extra(extra: str) -> str | None:
    """Why a figure cannot run without ``extra`` (what to install), or None when it is installed."""
    for module in EXTRA_MODULES[extra]:
        try:
            require_extra("blackmetal bench", extra, module)
        except MissingExtra:
            return f"needs the {extra} extra: pip install 'blackmetal[{extra}]'"
    return None


@dataclass(frozen=True)
class Plan:
    """How long and how often every figure measures."""

    quick: bool
    progress: Callable[[str], object]

    @property
    def rounds(self) -> int:
        return self.pick(1, 3)

    @property
    def samples(self) -> int:
        return self.pick(40, 200)

    @property
    def warmups(self) -> dict[str, float]:
        """--quick only proves every figure runs end to end: its warm-ups (before a window) are short, its figures mean nothing."""
        return {"warmup": 0.3} if self.quick else {}

    def pick(self, quick: T, full: T) -> T:
        """``quick`` with --quick, else ``full``: a figure's seconds or sample count."""
        return quick if self.quick else full


@dataclass(frozen=True)
class Figure:
    """One figure (or a few measured together): its name, how it is measured, what it is compared with, how it is printed."""

    name: str  # for --only, and in the result's "measured", "skipped" and "failed"
    title: str  # in its skip or failure line
    doing: str  # the progress line while it is measured
    keys: tuple[str, ...]  # its entries in the result
    measure: Callable[[Plan, Result], Result]  # given the result so far (its baselines), returns its entries
    rows: Callable[[Result], list[Row]]  # its rows of the table, from the whole result
    extra: str | None = None  # the optional extra it needs (EXTRA_MODULES)
    needs: tuple[str, ...] = ()  # figures whose results are its baseline
    within: str | None = None  # a figure that measures this one too: when that one runs, this one is not run apart


def noisy(values: list[float]) -> bool:
    return len(values) > 1 and min(values) > 0 and max(values) / min(values) > 2.0


def rounds(plan: Plan, **latencies: Callable[[], dict[str, float]]) -> dict[str, dict[str, list[float]]]:
    """Each latency measured once per round, in the order given (a baseline right before its figure): their p50s and p99s."""
    out: dict[str, dict[str, list[float]]] = {name: {"p50": [], "p99": []} for name in latencies}
    for _ in range(plan.rounds):
        for name, measure in latencies.items():
            result = measure()
            out[name]["p50"].append(result["p50_ms"])
            out[name]["p99"].append(result["p99_ms"])
    return out


def spreads(measured: dict[str, list[float]]) -> dict[str, Any]:
    return {p: {"median": statistics.median(v), "min": min(v), "max": max(v)} for p, v in measured.items()}


def over(figure: dict[str, list[float]], baseline: dict[str, list[float]], which: str = "p50") -> float:
    """The median over the rounds of the figure's ``which`` divided by the baseline's of the same round."""
    return statistics.median(f / b for f, b in zip(figure[which], baseline[which], strict=True))


def one_sentence(exc: Exception) -> str:
    """What went wrong, on one line: a child's own last line, a command's last line on stderr, or the error's text."""
    if isinstance(exc, ChildFailed):
        last = next((line.strip() for line in reversed(exc.child.lines) if line.strip()), "")
        head = str(exc).splitlines()[0].removesuffix("; its last lines:")
        return f"{head}: {last}" if last else head
    if isinstance(exc, subprocess.CalledProcessError):
        stderr = exc.stderr if isinstance(exc.stderr, str) else ""
        last = next((line.strip() for line in reversed(stderr.splitlines()) if line.strip()), "")
        return f"a helper process exited with code {exc.returncode}" + (f": {last}" if last else "")
    if isinstance(exc, BlackmetalError | OSError):
        lines = str(exc).splitlines()
        return lines[0] if lines else type(exc).__name__
    where = traceback.extract_tb(exc.__traceback__)[-1] if exc.__traceback__ else None
    place = f" at {Path(where.filename).name}:{where.lineno}" if where else ""
    return f"unexpected {type(exc).__name__}{place}: {exc} (a bug in the bench; please report it)"


def measure(figures: tuple[Figure, ...], quick: bool, progress: Callable[[str], object], only: set[str] | None) -> Result:
    """Every figure (or those in ``only`` and their baselines); one skipped or failed is a line and
    ``{"skipped": why}`` or ``{"failed": why}`` in the result, and the others still run."""
    plan = Plan(quick, progress)
    chosen = {figure.name for figure in figures} if only is None else set(only)
    for figure in reversed(figures):  # with their baselines: a figure only needs figures measured before it
        if figure.name in chosen:
            chosen.update(figure.needs)
    out: Result = {"quick": quick, "rounds": plan.rounds, "measured": [], "skipped": {}, "failed": {}}
    for figure in figures:
        if figure.name not in chosen or figure.within in chosen:
            continue
        why_not = missing_extra(figure.extra) if figure.extra else None
        for need in figure.needs:
            if why_not is None and (need in out["skipped"] or need in out["failed"]):
                why_not = f"needs the {need} figure as its baseline, which {'was skipped' if need in out['skipped'] else 'failed'}"
        if why_not is not None:
            progress(f"{figure.title}: skipped, {why_not}")
            out["skipped"][figure.name] = why_not
            out.update({key: {"skipped": why_not} for key in figure.keys})
            continue
        progress(figure.doing)
        try:
            out.update(figure.measure(plan, out))
            out["measured"].append(figure.name)
        except Exception as exc:
            failure = one_sentence(exc)
            progress(f"{figure.title}: failed, {failure}")
            out["failed"][figure.name] = failure
            out.update({key: {"failed": failure} for key in figure.keys})
        finally:
            children.stop_all()  # the net under the figure's own cleanup
    return out


def ms(value: dict[str, float]) -> str:
    return f"{value['median']:.3f} ms [{value['min']:.3f}-{value['max']:.3f}]"


def met(ok: bool) -> str:
    return ": met" if ok else ": MISSED"


def at_most(ratio: float, target: float, noisy: bool = False) -> str:
    """A ratio's verdict against its target: ``1.23x (<= 1.5x: met)``, NOISY when its rounds disagree."""
    return f"{ratio:.2f}x (<= {target:g}x{met(ratio <= target)})" + (" NOISY" if noisy else "")


def latency_rows(label: str, figure: Result, against: str, baseline: Result, p50_verdict: str, p99_verdict: str = "") -> list[Row]:
    """A latency's p50 and p99 rows, each beside its baseline's; ``{p}`` in ``label`` and ``against`` is p50 or p99."""
    return [
        (label.format(p=p), ms(figure[p]), f"{against.format(p=p)} {ms(baseline[p])}", verdict)
        for p, verdict in (("p50", p50_verdict), ("p99", p99_verdict))
    ]


def table(figures: dict[str, Figure], order: tuple[str, ...], f: Result) -> str:
    """The figures as a table, in ``order``; a skipped or failed figure is one row that says why."""
    rows: list[Row] = [("figure", "measured (median [min-max])", "baseline, same run", "ratio / target")]
    for name in order:
        if name in f["skipped"]:
            rows.append((figures[name].title, f"skipped, {f['skipped'][name]}", "", ""))
        elif name in f["failed"]:
            rows.append((figures[name].title, f"FAILED, {f['failed'][name]}", "", ""))
        elif name in f["measured"]:
            rows += figures[name].rows(f)
    widths = [max(len(row[i]) for row in rows) for i in range(4)]
    lines = [" | ".join(cell.ljust(widths[i]) for i, cell in enumerate(row)).rstrip() for row in rows]
    lines.insert(1, "-+-".join("-" * w for w in widths))
    return "\n".join(lines)
