"""The project's own rules, checked like behaviour: layers, lint, types, and docs that match the code."""

from __future__ import annotations

import re
import subprocess
import sys
from pathlib import Path

import pytest

from blackmetal.schemas import KEY_SPECS, Keys

ROOT = Path(__file__).resolve().parents[2]
BIN = Path(sys.executable).parent


def _run(args: list[str], timeout: float = 600) -> subprocess.CompletedProcess[str]:
    return subprocess.run(args, cwd=ROOT, capture_output=True, text=True, timeout=timeout)


def test_the_layers_hold_and_the_services_never_import_each_other() -> None:
    result = _run([str(BIN / "lint-imports")])
    assert result.returncode == 0, result.stdout + result.stderr
    assert "0 broken" in result.stdout


def test_ruff_finds_nothing() -> None:
    lint = _run([sys.executable, "-m", "ruff", "check", "."])
    assert lint.returncode == 0, lint.stdout + lint.stderr
    fmt = _run([sys.executable, "-m", "ruff", "format", "--check", "."])
    assert fmt.returncode == 0, fmt.stdout + fmt.stderr


def test_mypy_finds_nothing() -> None:
    result = _run([sys.executable, "-m", "mypy"])
    assert result.returncode == 0, result.stdout + result.stderr


def _section(title: str, page: str = "README.md") -> str:
    """The section ``## title`` of ``page`` (a path from the repository's root), up to the next section of that level."""
    text = (ROOT / page).read_text()
    start = text.index(f"\n## {title}\n")
    end = text.find("\n## ", start + 1)
    return text[start : end if end >= 0 else len(text)]


@pytest.mark.parametrize("page", ["README.md", "docs/concepts.md"])
def test_the_readme_key_table_lists_exactly_the_key_space(page: str) -> None:
    """The README's short key table and the full one in docs/concepts.md each list every key, and no other."""
    section = _section("Key expressions", page)
    rows = [line for line in section.splitlines() if line.startswith("| `robot/")]
    documented = {key for row in rows for key in re.findall(r"`(robot/[^`]+)`", row.split("|")[1])}
    keys = Keys("robot")
    assert documented == {getattr(keys, spec.name) for spec in KEY_SPECS}


def test_keys_follow_the_prefix_and_refuse_wildcards() -> None:
    fleet = Keys("fleet/a")
    assert fleet.cmd_vel == "fleet/a/cmd_vel" and fleet.impulses == "fleet/a/wheels/impulses"
    assert fleet.message_for("fleet/a/pose").__name__ == "Pose"  # type: ignore[union-attr]
    assert Keys.prefix_of_gateway_token(fleet.alive_gateway) == "fleet/a"
    for bad in ("", "robot/*", "a//b", "@robot", "r$"):
        with pytest.raises(Exception, match="prefix"):
            Keys(bad)


#: The folders at the top of the repository that install inside ``blackmetal`` (``blackmetal/<name>`` links to ``../<name>``).
SERVICE_FOLDERS = ("gateway", "odometry_service", "schemas")


def test_everything_imports_from_one_root() -> None:
    """``blackmetal.gateway``, never ``gateway``: names like ``gateway`` and ``schemas`` belong to other distributions too."""
    import ast

    offenders = []
    for path in sorted(
        {*ROOT.glob("blackmetal/**/*.py"), *ROOT.glob("tests/**/*.py"), *(p for f in SERVICE_FOLDERS for p in ROOT.glob(f"{f}/*.py"))}
    ):
        for node in ast.walk(ast.parse(path.read_text(), str(path))):
            names = [a.name for a in node.names] if isinstance(node, ast.Import) else []
            if isinstance(node, ast.ImportFrom) and node.level == 0 and node.module:
                names = [node.module]
            offenders += [f"{path.relative_to(ROOT)}: {name}" for name in names if name.split(".")[0] in SERVICE_FOLDERS]
    assert offenders == []
    for name in SERVICE_FOLDERS:
        link = ROOT / "blackmetal" / name
        assert link.is_symlink() and link.resolve() == (ROOT / name).resolve(), f"blackmetal/{name} must link to ../{name}"


def test_the_distribution_installs_one_top_level_package() -> None:
    """The installed distribution holds ``blackmetal/`` alone, the service folders inside it (CI installs it as users do)."""
    import json
    from importlib import metadata

    # the installed one, not the egg-info that building left in this checkout (the working directory is on sys.path)
    (dist,) = [d for d in metadata.distributions(name="blackmetal") if ".dist-info" in str(getattr(d, "_path", ""))]
    direct = dist.read_text("direct_url.json")
    if direct and json.loads(direct).get("dir_info", {}).get("editable"):
        pytest.skip("an editable install maps the source tree; CI's `pip install .` is checked")
    files = [str(f) for f in dist.files or []]
    tops = {f.split("/")[0] for f in files if not f.startswith("..") and ".dist-info" not in f.split("/")[0]}
    assert tops == {"blackmetal"}, tops
    for name in SERVICE_FOLDERS:
        assert f"blackmetal/{name}/__init__.py" in files
