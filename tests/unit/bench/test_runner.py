"""The bench's runner on made-up figures: which figures run, which are skipped and why, and the table's order.

No process starts: each figure's measurement is a function of this file.
"""

from __future__ import annotations

from blackmetal.bench import FIGURES, TABLE_ORDER
from blackmetal.bench.runner import Figure, Plan, Result, Row, measure, table


def _figure(name: str, ran: list[str], **kwargs: object) -> Figure:
    def run(plan: Plan, out: Result) -> Result:
        ran.append(name)
        if name == "broken":
            raise RuntimeError("made to fail")
        return {f"{name}_value": 1.0}

    def rows(f: Result) -> list[Row]:
        return [(f"{name} row", str(f[f"{name}_value"]), "-", "report")]

    return Figure(name, f"{name} title", f"measuring {name} ...", (f"{name}_value",), run, rows, **kwargs)  # type: ignore[arg-type]


def test_a_figure_within_another_runs_alone_only_when_the_other_does_not() -> None:
    ran: list[str] = []
    figures = (_figure("part", ran, within="whole"), _figure("whole", ran))
    assert measure(figures, True, lambda line: None, {"part"})["measured"] == ["part"]
    assert measure(figures, True, lambda line: None, {"part", "whole"})["measured"] == ["whole"]
    assert measure(figures, True, lambda line: None, None)["measured"] == ["whole"]
    assert ran == ["part", "whole", "whole"]


def test_a_figure_whose_baseline_failed_is_skipped_and_says_why() -> None:
    ran: list[str] = []
    lines: list[str] = []
    figures = (_figure("broken", ran), _figure("after", ran, needs=("broken",)))
    result = measure(figures, True, lines.append, {"after"})
    assert ran == ["broken"] and result["measured"] == []
    assert result["failed"]["broken"].startswith("unexpected RuntimeError at test_runner.py:")
    assert result["skipped"] == {"after": "needs the broken figure as its baseline, which failed"}
    assert "after title: skipped, needs the broken figure as its baseline, which failed" in lines
    text = table({figure.name: figure for figure in figures}, ("after", "broken"), result)
    cells = [[cell.strip() for cell in line.split("|")] for line in text.splitlines()[2:]]
    assert cells[0][:2] == ["after title", "skipped, needs the broken figure as its baseline, which failed"]
    assert cells[1][0] == "broken title" and cells[1][1].startswith("FAILED, unexpected RuntimeError")


def test_every_figure_is_in_the_table_once_and_the_forwarder_is_measured_within_cmd_vel() -> None:
    names = [figure.name for figure in FIGURES]
    assert sorted(TABLE_ORDER) == sorted(names) and len(set(names)) == len(names)
    forwarder = next(figure for figure in FIGURES if figure.name == "forwarder")
    assert forwarder.within == "cmd_vel" and names.index("forwarder") < names.index("cmd_vel")
