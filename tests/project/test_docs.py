"""The documentation holds to the code: the README as a front page, docs/ built strictly, the reference generated.

- docs/reference/configuration.md is what docs/generate_reference.py makes from the settings
  models now, and each command's --help lists exactly the options the page gives it;
- every link from the README (and CONTRIBUTING.md) into docs/ reaches a file and a heading;
- ``mkdocs build --strict`` passes (broken links and anchors are warnings, which strict fails);
- the README stays a front page: at most 300 lines, the quick start's two commands on its first
  screen, the test command the one .ci/run runs.
"""

from __future__ import annotations

import argparse
import importlib.util
import os
import re
import subprocess
import sys
from pathlib import Path
from types import ModuleType

import pytest

from blackmetal import cli

ROOT = Path(__file__).resolve().parents[2]
README = ROOT / "README.md"
DOCS = ROOT / "docs"
DEMO_COMMAND = "python3 -m venv .venv && . .venv/bin/activate && pip install . && blackmetal up"
TEST_COMMAND = "pip install '.[test]' && python -m pytest"
#: How many lines a newcomer sees before scrolling (a laptop's terminal or a repository page's first screen).
FIRST_SCREEN = 40


def generator() -> ModuleType:
    """docs/generate_reference.py, imported from its path (it is a script beside the docs, not a module of the package)."""
    spec = importlib.util.spec_from_file_location("generate_reference", DOCS / "generate_reference.py")
    assert spec is not None and spec.loader is not None
    module = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(module)
    return module


def test_the_configuration_reference_is_what_the_code_makes() -> None:
    page = DOCS / "reference" / "configuration.md"
    assert page.read_text() == generator().render(), "docs/reference/configuration.md is stale: run python docs/generate_reference.py"


def _options(text: str) -> set[str]:
    return set(re.findall(r"(?<![\w-])(--?[A-Za-z][\w-]*)", text)) - {"-h", "--help"}


def help_options(parser: argparse.ArgumentParser) -> set[str]:
    """The option strings ``blackmetal COMMAND --help`` prints: the start of each option line, up to its help text."""
    found: set[str] = set()
    for line in parser.format_help().splitlines():
        head = re.match(r"  (-\S.*?)(?:  |$)", line)
        if head:
            found |= _options(head.group(1))
    return found


def reference_sections() -> dict[str, str]:
    """Each command's section of the reference, by command name."""
    text = (DOCS / "reference" / "configuration.md").read_text()
    parts = re.split(r"^#{2,3} `blackmetal ([\w-]+)`\n", text, flags=re.M)
    return {parts[i]: re.split(r"^## ", parts[i + 1], flags=re.M)[0] for i in range(1, len(parts), 2)}


def reference_options(section: str) -> set[str]:
    """The options a section gives: the first column of its tables, and the Zenoh flags it points to."""
    found: set[str] = set()
    for line in section.splitlines():
        if line.startswith("| `"):
            found |= _options(line.split(" | ")[0])
        elif line.startswith("And the [Zenoh flags]"):
            found |= _options(line.partition(") ")[2])  # after the link's target: the flags themselves
    return found


def test_every_commands_help_lists_the_options_of_the_reference() -> None:
    parsers = generator().command_parsers()
    sections = reference_sections()
    assert set(sections) == set(parsers), "a command without a section in the reference, or a section without a command"
    assert set(parsers) == {*cli.COMMANDS, "schema"}
    for name, parser in parsers.items():
        in_help, on_page = help_options(parser), reference_options(sections[name])
        assert in_help, name
        assert in_help == on_page, (
            f"blackmetal {name}: only in --help {sorted(in_help - on_page)}, only on the page {sorted(on_page - in_help)}"
        )


def test_every_setting_is_an_option_with_the_file_key_and_variable_the_reference_names() -> None:
    """Each settings field is on the page as its option, its key and BLACKMETAL_<KEY>, and a variable of that name sets it."""
    import dataclasses

    from blackmetal.runtime.settings import load_settings

    module = generator()
    sections = reference_sections()
    for name, cls in module.SETTINGS.items():
        for f in dataclasses.fields(cls):
            if f.name == "zenoh":
                continue
            assert f"| `{f.name}`, `BLACKMETAL_{f.name.upper()}` |" in sections[name], (name, f.name)
    # the variable the page names is the one the settings read (a number, a list, a flag)
    env = {"BLACKMETAL_POLL_HZ": "75", "BLACKMETAL_SOURCE": "a:10,b:20", "BLACKMETAL_RELEASE_KEY_ONLY": "true"}
    settings = load_settings(module.SETTINGS["gateway"], {}, environ=env)
    assert (settings.poll_hz, settings.source, settings.release_key_only) == (75.0, ["a:10", "b:20"], True)


def test_the_zenoh_credentials_come_from_the_variables_the_reference_names(monkeypatch: pytest.MonkeyPatch) -> None:
    from blackmetal.runtime.zenoh_setup import ZenohSettings

    module = generator()
    page = (DOCS / "reference" / "configuration.md").read_text()
    for field_name, (variable, _) in module.ZENOH_ENV_ONLY.items():
        assert f"| `{variable}` |" in page
        monkeypatch.setenv(variable, f"value-of-{field_name}")
    settings = ZenohSettings()
    assert (settings.user, settings.password) == ("value-of-user", "value-of-password")


# --------------------------------------------------------------------------- links and headings


def _headings(page: Path) -> list[str]:
    """The text of every heading of a Markdown page, fenced code left out."""
    headings, fenced = [], False
    for line in page.read_text().splitlines():
        if line.startswith("```"):
            fenced = not fenced
        elif not fenced and re.match(r"#{1,6} ", line):
            text = line.lstrip("#").strip()
            text = re.sub(r"\[([^\]]*)\]\([^)]*\)", r"\1", text)  # a link: its text
            headings.append(text.replace("`", "").replace("*", ""))
    return headings


def mkdocs_slug(text: str) -> str:
    """The anchor MkDocs gives a heading (Python-Markdown's toc slugify)."""
    from markdown.extensions.toc import slugify

    return str(slugify(text, "-"))


def github_slug(text: str) -> str:
    """The anchor GitHub gives a heading: lower case, punctuation dropped, each space a hyphen."""
    return re.sub(r"[^\w\- ]", "", text.lower()).replace(" ", "-")


def _links_into_docs(page: Path) -> list[str]:
    return re.findall(r"\]\((docs/[^)\s]+)\)", page.read_text())


@pytest.mark.parametrize("page", ["README.md", "CONTRIBUTING.md"])
def test_every_link_into_docs_reaches_a_file_and_a_heading(page: str) -> None:
    """Read on GitHub or PyPI, the front page links into docs/: each target exists, and its anchor is a heading there."""
    links = _links_into_docs(ROOT / page)
    assert links, f"{page} links into nothing in docs/"
    for link in links:
        path, _, anchor = link.partition("#")
        target = ROOT / path
        assert target.is_file(), f"{page}: {link}: no such file"
        if anchor:
            headings = _headings(target)
            assert anchor in {mkdocs_slug(h) for h in headings}, f"{page}: {link}: no such heading in the built docs"
            assert anchor in {github_slug(h) for h in headings}, f"{page}: {link}: GitHub names that heading otherwise"


def test_the_docs_build_strictly(tmp_path: Path) -> None:
    """``mkdocs build --strict``: a page missing from the nav's targets, a broken link or anchor fails the build."""
    if importlib.util.find_spec("mkdocs") is None or importlib.util.find_spec("material") is None:
        pytest.skip("mkdocs or mkdocs-material is not installed (both come with the test extra)")
    env = {**os.environ, "NO_MKDOCS_2_WARNING": "1"}
    done = subprocess.run(
        [sys.executable, "-m", "mkdocs", "build", "--strict", "-q", "-f", str(ROOT / "mkdocs.yml"), "-d", str(tmp_path / "site")],
        capture_output=True,
        text=True,
        timeout=120,
        env=env,
    )
    assert done.returncode == 0, done.stdout + done.stderr
    assert (tmp_path / "site" / "reference" / "configuration" / "index.html").is_file()


# --------------------------------------------------------------------------- the front page


def test_the_readme_is_a_front_page_with_the_two_commands_on_its_first_screen() -> None:
    lines = README.read_text().splitlines()
    assert len(lines) <= 300, f"the README has {len(lines)} lines; the front page holds at most 300, the rest goes to docs/"
    first_screen = "\n".join(lines[:FIRST_SCREEN])
    assert DEMO_COMMAND in first_screen
    assert f"python3 -m venv .venv && . .venv/bin/activate && {TEST_COMMAND}" in first_screen


def test_ci_runs_the_readmes_test_command_verbatim() -> None:
    ci = (ROOT / ".ci" / "run").read_text()
    assert f"\n{TEST_COMMAND}\n" in ci
    assert TEST_COMMAND in README.read_text()


def test_the_quick_start_holds_no_contributor_notes() -> None:
    """The quick start is for a newcomer: what CI runs and the fast tier live in docs/contributing.md."""
    text = README.read_text()
    start = text.index("\n## Quick start\n")
    quick_start = text[start : text.index("\n## ", start + 1)]
    for note in (".ci/run", "not slow", "xdist", "CI"):
        assert note not in quick_start, note


def test_the_python_example_of_getting_started_is_the_readmes() -> None:
    """tests/integration/test_user_tools.py runs the README's block verbatim; the docs show the same block."""

    def block(text: str) -> str:
        found = re.search(r"```python\n(.*?)```", text, re.S)
        assert found is not None
        return found.group(1)

    assert block((DOCS / "getting-started.md").read_text()) == block(README.read_text())
