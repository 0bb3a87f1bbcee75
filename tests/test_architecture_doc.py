"""docs/ARCHITECTURE.md is the map of the code (issue 87): it names no file that does not exist, and every module of
the two packages is on it."""
from __future__ import annotations

import re
import subprocess
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
DOC = ROOT / "docs" / "ARCHITECTURE.md"


def _files() -> list[str]:
    out = subprocess.run(["git", "ls-files", "--cached", "--others", "--exclude-standard"], cwd=ROOT,
                         capture_output=True, text=True, check=True).stdout.split()
    return [f for f in out if (ROOT / f).exists()]


def _named(doc: str) -> tuple[set[str], set[str]]:
    """``(bare module names, paths)`` the page names: ``errors.py`` in the package tree, ``conf/row/seed_whole.yaml``
    in the text."""
    paths = set(re.findall(r"(?<![\w.<>-])((?:[\w.-]+/)+[\w.-]+\.(?:py|yaml|md|json|csv|png))", doc))
    names = set(re.findall(r"(?<![\w/.<>-])([A-Za-z_]\w*\.py)\b", doc)) | {Path(p).name for p in paths}
    return names, paths


def test_the_map_names_no_file_that_does_not_exist():
    files = _files()
    names, paths = _named(DOC.read_text(encoding="utf-8"))
    basenames = {Path(f).name for f in files}
    assert sorted(n for n in names if n not in basenames) == []
    assert sorted(p for p in paths if not any(f == p or f.endswith("/" + p) for f in files)) == []


def test_every_module_is_on_the_map():
    names, _ = _named(DOC.read_text(encoding="utf-8"))
    modules = [f for f in _files() if f.endswith(".py") and f.split("/")[0] in ("imls_lightning", "data_gen")
               and not f.endswith("__init__.py")]
    assert sorted(f for f in modules if Path(f).name not in names) == []


def test_the_checks_see_a_missing_file():
    names, paths = _named("  gone.py    a module\nsee conf/row/nowhere.yaml\n")
    assert "gone.py" in names and "conf/row/nowhere.yaml" in paths
