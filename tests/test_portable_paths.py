"""No committed file names an absolute path on someone's machine (issue 87): a command, config or document that does
runs nowhere else (the flame_whole row scripts once `cd`-ed into one)."""
from __future__ import annotations

import re
import subprocess
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]

#: an absolute path under a machine's own folders: work trees, home folders, scratch space. Not one preceded by a
#: letter, digit, dot, slash or ~ (`runs/tmp/`, `https://host/home/`, `~/work/` are not absolute paths of a machine)
ABSOLUTE = re.compile(r"(?<![\w.~/])/(?:work|home|tmp|root|Users)/")
#: records a program wrote of a run that happened: they say where that run read and wrote, and rewriting them would
#: change history, not make a command portable. Logs anywhere; under benchmarks/ the JSON and CSV results, the
#: evaluation and reproduction reports (*report.md) and paper_scale.md (bench_paper writes it from
#: paper_scale_pairs.json, each pair's record)
RECORDS = re.compile(r"(\.log$)|(^benchmarks/.*(\.json|\.csv|report\.md)$)|(^benchmarks/paper_scale\.md$)")


def absolute_paths(files: list[str], root: Path = ROOT) -> list[str]:
    """``path:line: text`` for each line of a text file among ``files`` (relative to ``root``) that names an
    absolute machine path; binary files (a NUL byte, or not UTF-8) and :data:`RECORDS` are left out."""
    found = []
    for name in files:
        if RECORDS.search(name):
            continue
        try:
            data = (root / name).read_bytes()
        except (FileNotFoundError, IsADirectoryError):  # deleted in the work tree, or a submodule
            continue
        if b"\0" in data:
            continue
        try:
            text = data.decode("utf-8")
        except UnicodeDecodeError:
            continue
        found += [f"{name}:{n}: {line.strip()[:160]}" for n, line in enumerate(text.splitlines(), 1) if ABSOLUTE.search(line)]
    return found


def test_no_committed_file_names_an_absolute_path():
    """Every tracked text file but the records (:data:`RECORDS`): a path in the work, home, tmp, root or Users folder
    at a file system's root is a path on one machine. Examples use a relative path or a placeholder (`<cache>`); a
    test's scratch files live in pytest's tmp_path, never in a named absolute folder."""
    files = subprocess.run(["git", "ls-files", "-z"], cwd=ROOT, capture_output=True, check=True).stdout.decode().split("\0")
    assert absolute_paths([f for f in files if f]) == []


def test_what_counts_as_an_absolute_path(tmp_path):
    work, tmp = "/" + "work/", "/" + "tmp/"  # built, so that this file names none itself
    (tmp_path / "benchmarks").mkdir()
    lines = {"cmd.sh": f"cd {work}main && make\n", "doc.md": "see runs/tmp/x and https://host/home/y and ~/work/z\n",
             "conf.yaml": f"out: '{tmp}B.md'\n", "benchmarks/run.log": f"{work}main/runs\n",
             "benchmarks/eval_report.md": f"`{work}main/runs/a.ckpt`\n", "blob.bin": f"\0{work}x\n"}
    for name, text in lines.items():
        (tmp_path / name).write_text(text)
    assert absolute_paths(sorted(lines), tmp_path) == [f"cmd.sh:1: cd {work}main && make", f"conf.yaml:1: out: '{tmp}B.md'"]
