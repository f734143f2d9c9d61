"""docs/threads.md names only what exists: every module, class, function and attribute it puts in backticks.

Checked are the backticked names that look like code: a path ending in
``.py``, a dotted name (``Driver.lock``, ``gc.freeze()``), a CamelCase or
ALL_CAPS name, and a ``name()`` call. Plain words (``estop``, ``now``), keys
(``cmd_vel/<source>``) and argument lists are text. A dotted name resolves
by importing (``blackmetal.runtime.driver``, ``sys``), or by its first part
among the names of the product's modules, then attribute by attribute (an
instance attribute counts when its class sets or declares it).
"""

from __future__ import annotations

import functools
import importlib
import inspect
import pkgutil
import re
from pathlib import Path
from typing import Any

import pytest

import blackmetal

ROOT = Path(__file__).resolve().parents[2]
DOC = ROOT / "docs" / "threads.md"
CODE = re.compile(r"^[A-Za-z_]\w*(\.[A-Za-z_]\w*)*(\(\))?$")


def backticked(text: str) -> list[str]:
    return sorted(set(re.findall(r"`([^`\n]+)`", text)))


def looks_like_code(token: str) -> bool:
    if token.endswith(".py"):
        return True
    if not CODE.match(token):
        return False
    name = token.removesuffix("()")
    return token.endswith("()") or "." in name or name.isupper() or any(c.isupper() for c in name[1:]) or name[0].isupper()


@functools.cache
def product_names() -> dict[str, list[Any]]:
    """Every global of every product module, by name (what a bare ``Intake`` or ``wire`` may mean)."""
    names: dict[str, list[Any]] = {}
    for info in pkgutil.walk_packages(blackmetal.__path__, "blackmetal."):
        if info.name.endswith("__main__"):
            continue
        module = importlib.import_module(info.name)
        for name, value in vars(module).items():
            names.setdefault(name, []).append(value)
    return names


def has_attribute(owner: Any, name: str) -> Any:
    """``owner.name``, or True for an instance attribute its class declares or sets; None when there is none."""
    if hasattr(owner, name):
        return getattr(owner, name)
    if inspect.isclass(owner):
        for cls in inspect.getmro(owner):
            if name in getattr(cls, "__dataclass_fields__", {}) or name in getattr(cls, "__annotations__", {}):
                return True
            try:
                if re.search(rf"\bself\.{re.escape(name)}\b", inspect.getsource(cls)):
                    return True
            except (OSError, TypeError):
                continue
    return None


def resolves(token: str, names: dict[str, list[Any]]) -> bool:
    if token.endswith(".py"):
        return (ROOT / token).exists()
    parts = token.removesuffix("()").split(".")
    starts: list[tuple[Any, list[str]]] = []
    for cut in range(len(parts), 0, -1):
        try:
            starts.append((importlib.import_module(".".join(parts[:cut])), parts[cut:]))
            break
        except ImportError:
            continue
    starts += [(value, parts[1:]) for value in names.get(parts[0], [])]
    for owner, rest in starts:
        for name in rest:
            owner = has_attribute(owner, name)
            if owner is None:
                break
            if owner is True:  # an instance attribute: nothing further to look into
                owner = object()
        else:
            return True
    return False


def test_every_name_in_the_thread_page_exists() -> None:
    names = product_names()
    tokens = [t for t in backticked(DOC.read_text()) if looks_like_code(t)]
    assert len(tokens) > 30, "the page names the driver, its lock, timer and rule"
    missing = [t for t in tokens if not resolves(t, names)]
    assert missing == [], f"docs/threads.md names what does not exist: {missing}"


@pytest.mark.parametrize("token", ["Driver.nothing_such", "blackmetal/runtime/host.py", "DeadlineTimer", "DirectPath.lock", "gone()"])
def test_a_name_that_no_longer_exists_is_caught(token: str) -> None:
    assert looks_like_code(token)
    assert not resolves(token, product_names())


def test_plain_words_and_keys_are_text() -> None:
    assert not any(looks_like_code(t) for t in ["estop", "now", "cmd_vel/<source>", "(source, bytes)", "_locked"])
