"""The documented commands, collected, and how one of them is run.

The commands are collected from README.md and docs/*.md (fenced and indented code blocks,
inline code spans that begin with ``mtplan``) and from the header comments of the files in
``examples/``. A span with a placeholder (``PROC``, ``FILE``, ``NAME``, ``...``, ``A|B``,
``[--json]``) is a template, not a command line; a header command with ``PROC`` is run for
every procedure with an ``examples/PROC_readings.csv``. A command that several documents
hold is tested once, with the first of them (README.md, then docs/ in name order, then
examples/): ``test_readme.py``, ``test_docs.py`` and ``test_examples.py`` each run their
own, one test per command, so that the test workers share them out.

Each command runs in this process (mtplan imported once) in a scratch folder holding a copy
of ``examples/`` (so a command that writes there changes nothing), with ``MTPLAN_MAX_TRIALS``
capping its Monte Carlo trials. ``mtplan demo`` and ``mtplan report examples/demo.toml``
compute the shipped study, which ``tests/reports/test_report.py::test_demo_end_to_end`` runs
end to end: here they are parsed and their study loaded.
"""

from __future__ import annotations

import contextlib
import glob
import io
import json
import re
import shlex
import shutil
import traceback
from fnmatch import fnmatch
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[2]
EXAMPLES = ROOT / "examples"
DOCUMENTS = [ROOT / "README.md", *sorted((ROOT / "docs").glob("*.md"))]
#: the trial cap of every command here (the planner's confirmation needs 100)
MAX_TRIALS = "100"
#: words that stand for a value the reader fills in
PLACEHOLDERS = {"PROC", "FILE", "NAME", "DIR", "SPEC", "SIGMA", "MEASURAND", "P", "M", "V", "F",
                "L", "U", "Y", "S", "N", "u", "LO", "HI", "V1", "V2"}
#: a placeholder as a word of its own or a part of a name (examples/PROC_readings.csv)
WORD = r"(?<![A-Za-z]){}(?![A-Za-z])"
#: commands whose full run is another test's (the demo study takes minutes)
STUDY_COMMANDS = {"demo", "report"}
#: commands that serve until stopped: started on a free loopback port, asked for their page
SERVER_COMMANDS = {"explore"}


def _template(words) -> bool:
    for word in words:
        if "..." in word or "|" in word or word.startswith("["):
            return True
        for part in re.split(r"[=,:<>]+", word):
            if part in PLACEHOLDERS or re.fullmatch(r"[A-Z][A-Z_]*\.(csv|toml)", part):
                return True
    return False


def _command(text):
    """The argv of an ``mtplan ...`` line (without a trailing comment), None for a template
    or a bare reference to a command (``mtplan estimate`` in a sentence)."""
    text = text.strip().removeprefix("$ ").strip()
    if not text.startswith("mtplan "):
        return None
    words = shlex.split(text, comments=True)[1:]
    if _template(words) or (len(words) == 1 and words[0] not in ("procedures", "demo")):
        return None
    return words


def _from_documents():
    found = []
    for path in DOCUMENTS:
        text = path.read_text(encoding="utf-8")
        blocks = re.findall(r"```[^\n]*\n(.*?)```", text, re.S)
        prose = re.sub(r"```.*?```", "", text, flags=re.S)
        lines = [line for b in blocks for line in b.splitlines()]
        lines += [line for line in prose.splitlines() if line.startswith("    ")]
        spans = re.findall(r"`([^`]+)`", prose.replace("\n", " "))
        for item in lines + spans:
            argv = _command(re.sub(r"\s+", " ", item))
            if argv is not None:
                found.append((path.relative_to(ROOT).as_posix(), argv))
    return found


def _header(path):
    """The leading comment lines of an example file."""
    lines = []
    for line in path.read_text(encoding="utf-8").splitlines():
        if not line.startswith("#"):
            break
        lines.append(line.lstrip("#").strip())
    return lines


def _from_examples():
    from mtplan.models import registry

    readings = sorted(p for p in EXAMPLES.glob("*_readings.csv")
                      if p.name.removesuffix("_readings.csv") in registry())
    found = []
    for path in sorted(p for p in EXAMPLES.iterdir() if p.suffix in (".toml", ".csv")):
        lines = _header(path)
        texts = [line.removeprefix("Run: ") for line in lines
                 if line.startswith(("mtplan ", "Run: mtplan "))]
        texts += re.findall(r"`(mtplan [^`]+)`", " ".join(lines))
        for text in texts:
            for proc in ([p.name.removesuffix("_readings.csv") for p in readings]
                         if re.search(WORD.format("PROC"), text) else [None]):
                if proc is not None:
                    text_p = re.sub(WORD.format("PROC"), proc, text)
                    text_p = re.sub(WORD.format("FILE"), f"examples/{proc}_readings.csv", text_p)
                else:
                    text_p = text
                argv = _command(text_p)
                if argv is not None:
                    found.append((path.relative_to(ROOT).as_posix(), argv))
    return found


EXAMPLE_COMMANDS = _from_examples()
DOCUMENT_COMMANDS = _from_documents()
#: every distinct command -> the first file that documents it
FIRST_SOURCE = {}
for _source, _argv in DOCUMENT_COMMANDS + EXAMPLE_COMMANDS:
    FIRST_SOURCE.setdefault(tuple(_argv), _source)
COMMANDS = sorted(FIRST_SOURCE)


def documented_first_in(pattern: str) -> list[tuple]:
    """The commands whose first source (:data:`FIRST_SOURCE`) matches `pattern` (a glob
    relative to the repository)."""
    return [argv for argv in COMMANDS if fnmatch(FIRST_SOURCE[argv], pattern)]


def command_id(argv) -> str:
    """A test id: the command line, cut at 70 characters."""
    return " ".join(argv)[:70]


def run(argv, folder: Path):
    """One command in this process, in `folder` holding a copy of ``examples/``: (status,
    stdout, stderr). The working folder and the trial cap are this call's only."""
    from mtplan.cli import main

    shutil.copytree(EXAMPLES, folder / "examples")
    with pytest.MonkeyPatch.context() as mp:
        mp.setenv("MTPLAN_MAX_TRIALS", MAX_TRIALS)
        mp.chdir(folder)
        if argv[0] in SERVER_COMMANDS:
            return _serve_once(argv)
        argv = [w for word in argv for w in (sorted(glob.glob(word)) or [word] if "*" in word
                                             else [word])]  # as the shell expands a pattern
        out, err = io.StringIO(), io.StringIO()
        with contextlib.redirect_stdout(out), contextlib.redirect_stderr(err):
            try:
                code = (_check_study_command(argv) if argv[0] in STUDY_COMMANDS
                        else main(list(argv)))
            except Exception:  # noqa: BLE001 - reported by the command's own test
                code = "exception"
                err.write(traceback.format_exc())
        return code, out.getvalue(), err.getvalue()


def check(argv, outcome) -> None:
    """The command ended with status 0, without a traceback, its ``--json`` output JSON."""
    code, out, err = outcome
    assert code == 0, f"mtplan {shlex.join(argv)}: status {code}\n{err[-2000:]}"
    assert "Traceback" not in err
    if "--json" in argv:
        json.loads(out)


def _serve_once(argv):
    """``explore``: the command as written plus ``--no-browser --port P`` (a free loopback
    port) in its own process, until the page of the link it prints (with this launch's
    token) answers; then it is stopped."""
    import socket
    import subprocess
    import sys
    import time
    import urllib.request

    with socket.socket() as sock:
        sock.bind(("127.0.0.1", 0))
        port = sock.getsockname()[1]
    cmd = [sys.executable, "-m", "mtplan.cli", *argv, "--no-browser", "--port", str(port)]
    proc = subprocess.Popen(cmd, stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
    status, deadline = "no answer within 120 s", time.monotonic() + 120
    try:
        line = proc.stdout.readline()  # "mtplan explore: serving on http://...?token=... "
        found = re.search(r"(http://127\.0\.0\.1:\d+/\?token=\S+)", line)
        if found is None:
            status = f"no link printed: {line.strip()!r}"
        while found and time.monotonic() < deadline and proc.poll() is None:
            try:
                opener = urllib.request.build_opener(urllib.request.HTTPCookieProcessor())
                with opener.open(found.group(1), timeout=5) as page:
                    status = 0 if page.status == 200 else f"HTTP {page.status}"
                    break
            except OSError:
                time.sleep(0.5)
    finally:
        proc.terminate()
        try:
            out, err = proc.communicate(timeout=10)
        except subprocess.TimeoutExpired:
            proc.kill()
            out, err = proc.communicate()
    return status, out, err


def _check_study_command(argv) -> int:
    """``demo`` / ``report``: the line parses and its study loads (run in full elsewhere)."""
    from mtplan.cli import build_parser
    from mtplan.cli.report import demo_study_path
    from mtplan.plans.study import load_study

    args = build_parser().parse_args(list(argv))
    study = demo_study_path() if argv[0] == "demo" else Path(args.study)
    assert study.resolve() == (EXAMPLES / "demo.toml").resolve() or argv[0] == "report"
    load_study(study)
    return 0
