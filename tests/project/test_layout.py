"""The test layout a newcomer relies on: the tests of ``blackmetal/<package>/<module>.py`` are in
``tests/unit/<package>/test_<module>.py`` (or ``test_<module>_<aspect>.py``), top-level modules under
``tests/unit/blackmetal/``; a subpackage's module ``<package>/<sub>/<module>.py`` in ``tests/unit/<package>/test_<sub>_<module>.py``,
and a package's ``__init__`` that holds code in ``test_<package name>.py``; docs/contributing.md ("Tests") draws it.

Every product module has its test file: a new module comes with one.
"""

from __future__ import annotations

from pathlib import Path

ROOT = Path(__file__).resolve().parents[2]
UNIT = ROOT / "tests" / "unit"

#: Modules that need no test file of their own, and why.
EXEMPT = {
    "__init__": "a package's docstring and re-exports; what it re-exports is tested where it is defined",
    "__main__": "``python -m`` calls the entry point; the entry is tested through the command",
}
#: These ``__init__`` modules are the command itself, not re-exports: tested in test_bench.py and test_up.py.
NOT_EXEMPT = {"bench/__init__", "tools/up/__init__"}

#: Folders of tests/unit that are no Python package of the product, and what they test.
OTHER_UNIT_FOLDERS = {"blackmetal": "the top-level modules blackmetal/*.py", "deploy": "the configurations in deploy/"}


def product_modules() -> list[str]:
    """``package/module`` (``package/sub/module`` in a subpackage) for every module of the product (``blackmetal/module``
    for the top level), symlinked packages included."""
    modules = [f"blackmetal/{path.stem}" for path in (ROOT / "blackmetal").glob("*.py")]
    for package in (ROOT / "blackmetal").iterdir():
        if package.is_dir() and (package / "__init__.py").is_file():  # gateway, odometry_service, schemas are symlinks
            modules += [f"{package.name}/{path.relative_to(package).with_suffix('').as_posix()}" for path in package.rglob("*.py")]
    return sorted(modules)


def has_test_file(module: str) -> bool:
    package, *path = module.split("/")
    name = "_".join(path[:-1] if path[-1] == "__init__" else path) or package  # tools/up/status: test_up_status
    folder = UNIT / package
    return (folder / f"test_{name}.py").is_file() or any(folder.glob(f"test_{name}_*.py"))


def test_every_product_module_has_its_test_file() -> None:
    wanted = [m for m in product_modules() if m.split("/")[-1] not in EXEMPT or m in NOT_EXEMPT]
    missing = sorted(m for m in wanted if not has_test_file(m))
    assert not missing, f"no tests/unit/<package>/test_<module>.py for {missing}: write it"


def test_every_unit_folder_is_named_after_what_it_tests() -> None:
    packages = {m.split("/")[0] for m in product_modules()}
    folders = {path.name for path in UNIT.iterdir() if path.is_dir() and path.name != "__pycache__"}
    assert folders - packages - set(OTHER_UNIT_FOLDERS) == set(), "tests/unit/<folder> is a package of blackmetal/"


def test_test_modules_live_in_the_folder_of_their_kind() -> None:
    """Only the shared helpers stay in tests/ itself; a test module goes to unit/, contract/, integration/ or project/."""
    loose = sorted(path.name for path in (ROOT / "tests").glob("test_*.py"))
    assert loose == [], f"{loose}: move each to tests/unit/<package>/, contract/, integration/ or project/"
    for folder in ("unit", "contract", "integration", "project"):
        top = ROOT / "tests" / folder
        for path in [top, *top.rglob("*")]:
            if path.is_dir() and path.name != "__pycache__":
                assert (path / "__init__.py").is_file(), (
                    f"{path.relative_to(ROOT)} needs an __init__.py: same-named test modules in two folders"
                )
