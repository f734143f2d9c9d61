"""The error tree drawn in ``schemas/errors.py`` is the real one: every class, its parent and its module.

The classes are found, not listed: every module of the project's packages
is imported, and every class deriving from ``BlackmetalError`` must be drawn
under its real parent with the module that defines it, so a new error, a new
parent or a module renamed in a refactor shows up here. Exceptions outside
the root are refused too: there is one root.
"""

from __future__ import annotations

import importlib
import pkgutil
import re
from dataclasses import dataclass
from types import ModuleType

import pytest

import blackmetal.schemas.errors as schemas_errors
from blackmetal.schemas import BlackmetalError

PACKAGES = ("blackmetal",)

#: One line of the drawing: tree prefix, class name, other bases, module, description.
LINE = re.compile(
    r"^(?P<indent>(?:│   |    )*)(?P<branch>[├└]── )?(?P<name>[A-Za-z_]\w*)"
    r"(?: \(also (?P<also>[\w, ]+)\))?\s+(?P<module>[a-z_][\w.]*)(?::\s.*)?$"
)


@dataclass(frozen=True)
class Drawn:
    name: str
    parent: str | None
    module: str
    also: tuple[str, ...]


def drawn_tree() -> dict[str, Drawn]:
    """The tree in the docstring of ``blackmetal.schemas.errors``, by class name."""
    doc = schemas_errors.__doc__ or ""
    block = doc.split("::\n", 1)[1]
    lines = [line[4:] for line in block.splitlines() if line.strip()]
    assert lines, "no tree drawn in schemas.errors"
    tree: dict[str, Drawn] = {}
    path: list[str] = []  # the names on the way from the root to the current line
    for line in lines:
        match = LINE.match(line)
        assert match, f"cannot read this line of the drawn tree: {line!r}"
        depth = len(match["indent"]) // 4 + (1 if match["branch"] else 0)
        assert depth <= len(path), f"{match['name']} is drawn deeper than a child of the line above"
        del path[depth:]
        name = match["name"]
        assert name not in tree, f"{name} is drawn twice"
        also = tuple(a.strip() for a in match["also"].split(",")) if match["also"] else ()
        tree[name] = Drawn(name, path[-1] if path else None, match["module"], also)
        path.append(name)
    return tree


def _ours(name: str) -> bool:
    return name.split(".")[0] in PACKAGES


def import_everything() -> list[ModuleType]:
    """Every module of the project's packages (``__main__`` modules run a command: not imported).

    A module is skipped only when a package that is not ours is missing (an
    optional extra); a module of ours that fails to import fails the test.
    """
    modules = []
    for package_name in PACKAGES:
        package = importlib.import_module(package_name)
        modules.append(package)
        for info in pkgutil.walk_packages(package.__path__, package_name + "."):
            if info.name.rsplit(".", 1)[-1] == "__main__":
                continue
            try:
                modules.append(importlib.import_module(info.name))
            except ImportError as exc:
                if exc.name is None or _ours(exc.name):
                    raise
    return modules


def _subclasses(cls: type) -> set[type]:
    found = set()
    for sub in cls.__subclasses__():
        found.add(sub)
        found |= _subclasses(sub)
    return found


@pytest.fixture(scope="module")
def real_tree() -> dict[str, type]:
    import_everything()
    classes = [BlackmetalError, *(c for c in _subclasses(BlackmetalError) if _ours(c.__module__))]
    names = [c.__name__ for c in classes]
    assert len(set(names)) == len(names), f"two errors share a name, the drawing cannot tell them apart: {sorted(names)}"
    return {c.__name__: c for c in classes}


def test_every_error_is_drawn_under_its_real_parent_with_its_module(real_tree: dict[str, type]) -> None:
    drawn = drawn_tree()
    assert set(real_tree) - set(drawn) == set(), "errors missing from the tree in schemas/errors.py"
    assert set(drawn) - set(real_tree) == set(), "drawn in schemas/errors.py but not (or no longer) a BlackmetalError"
    for name, cls in real_tree.items():
        entry = drawn[name]
        assert entry.module == cls.__module__, f"{name} is defined in {cls.__module__}, drawn in {entry.module}"
        ours = [b for b in cls.__bases__ if issubclass(b, BlackmetalError)]
        others = tuple(b.__name__ for b in cls.__bases__ if not issubclass(b, BlackmetalError) and b is not Exception)
        parent = ours[0].__name__ if ours else None
        assert len(ours) <= 1, f"{name} has two parents in the tree: {ours}"
        assert entry.parent == parent, f"{name} derives from {parent}, drawn under {entry.parent}"
        assert entry.also == others, f"{name} also derives from {others}, drawn as {entry.also}"


def test_there_is_one_root() -> None:
    """Every exception class the project defines derives from BlackmetalError."""
    outside = sorted(
        f"{value.__module__}.{value.__qualname__}"
        for module in import_everything()
        for value in vars(module).values()
        if isinstance(value, type)
        and issubclass(value, BaseException)
        and _ours(value.__module__)
        and not issubclass(value, BlackmetalError)
    )
    assert outside == [], "exceptions outside the root schemas.BlackmetalError"


def test_the_drawing_is_read_as_drawn() -> None:
    tree = drawn_tree()
    assert tree["BlackmetalError"].parent is None
    assert tree["MissingExtra"].parent == "ConfigError" and tree["ConfigError"].parent == "BlackmetalError"
    assert tree["PayloadError"].also == ("ValueError",)
    assert tree["ToolError"].parent == "BlackmetalError"  # the last branch, after a deeper one
