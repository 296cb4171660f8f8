"""The commands of README.md and docs/*.md, exactly as written, and a place to run them.

Which lines are documented commands (one rule, applied to every fenced block of README.md and
docs/*.md):

* a block tagged ``sh``, ``bash``, ``shell`` or ``console`` is a command block: every line
  that is not blank and not a comment starts a command, and a line that starts with
  whitespace (after a ``\\`` or not) continues the one before;
* in any other block that is not code (no tag, or ``text``), a line ``$ COMMAND`` is a command
  and the lines after it, up to the next ``$`` line, are the output the doc quotes for it; a
  line starting ``trackflow `` or ``make `` is a command without quoted output
  (``trackflow: ...`` lines are output, not commands);
* blocks of code (``python``, ``yaml``, ``json`` ...) hold no commands (README's Python example
  is run by ``test_readme_example_runs_and_propagates_lever_arm_error``).

A command is run by ``bash -c`` with its text as written (continuation lines and comments
included) in a directory laid out like a checkout beside the shared data: ``repo/`` (the
working directory) holds copies of ``examples/`` and ``docs/cli/`` and a ``.venv/bin`` whose
``trackflow`` and ``python`` run the trackflow under test; ``../shared/data`` is the shared
recordings; ``trackflow`` is on ``PATH``.
"""

from __future__ import annotations

import os
import re
import shutil
import signal
import subprocess
import sys
import time
from dataclasses import dataclass
from pathlib import Path

from conftest import REPO_ROOT

COMMAND_TAGS = {"sh", "bash", "shell", "console"}
TEXT_TAGS = {"", "text"}


@dataclass(frozen=True)
class DocCommand:
    """One documented command: where it is, its text as written, the output quoted after it."""

    doc: str  # path relative to the repository root
    line: int  # line of the command's first line in the doc (1-based)
    text: str  # as written, continuation lines included, the prompt "$ " removed
    expected: str = ""  # the output the doc quotes right after it (only after "$ " lines)

    @property
    def key(self) -> str:
        """The text as the shell reads it (a backslash-newline joins lines), whitespace runs
        made one space: the key of the test's tables."""
        return " ".join(self.text.replace("\\\n", " ").split())

    @property
    def where(self) -> str:
        return f"{self.doc}:{self.line}"


def doc_files() -> list[Path]:
    return [REPO_ROOT / "README.md", *sorted((REPO_ROOT / "docs").glob("*.md"))]


def _blocks(text: str):
    """(tag, first line number of the body, body lines) of every fenced block."""
    lines = text.splitlines()
    i = 0
    while i < len(lines):
        m = re.match(r"^(\s*)```(\S*)\s*$", lines[i])
        if not m:
            i += 1
            continue
        indent, tag = m.group(1), m.group(2).lower()
        j = i + 1
        while j < len(lines) and lines[j].strip() != "```":
            j += 1
        yield (
            tag,
            i + 2,
            [ln[len(indent) :] if ln.startswith(indent) else ln for ln in lines[i + 1 : j]],
        )
        i = j + 1


def block_before(cmd: DocCommand, tag: str) -> str:
    """The body of the last ``tag`` block (``yaml``, ...) of ``cmd``'s doc before ``cmd``: the
    file a command's text refers to."""
    text = (REPO_ROOT / cmd.doc).read_text()
    bodies = [body for t, first, body in _blocks(text) if t == tag and first < cmd.line]
    assert bodies, f"{cmd.where}: no {tag} block before it"
    return "\n".join(bodies[-1]) + "\n"


def _is_comment_or_blank(line: str) -> bool:
    return not line.strip() or line.lstrip().startswith("#")


def _command_block(doc: str, first: int, body: list[str]) -> list[DocCommand]:
    out: list[DocCommand] = []
    start, cur = 0, []
    for k, ln in enumerate(body):
        continues = cur and (ln[:1].isspace() or cur[-1].rstrip().endswith("\\")) and ln.strip()
        if continues:
            cur.append(ln)
            continue
        if cur:
            out.append(DocCommand(doc, first + start, "\n".join(cur)))
            cur = []
        if not _is_comment_or_blank(ln):
            start, cur = k, [ln]
    if cur:
        out.append(DocCommand(doc, first + start, "\n".join(cur)))
    return out


def _prompt_block(doc: str, first: int, body: list[str]) -> list[DocCommand]:
    out: list[DocCommand] = []
    k = 0
    while k < len(body):
        ln = body[k]
        if ln.startswith("$ "):
            start, cur = k, [ln[2:]]
            while cur[-1].rstrip().endswith("\\") and k + 1 < len(body):
                k += 1
                cur.append(body[k])
            k += 1
            quoted = []
            while k < len(body) and not body[k].startswith("$ "):
                quoted.append(body[k])
                k += 1
            out.append(DocCommand(doc, first + start, "\n".join(cur), "\n".join(quoted).strip()))
            continue
        if re.match(r"(trackflow|make) ", ln):
            out.append(DocCommand(doc, first + k, ln))
        k += 1
    return out


def documented_commands() -> list[DocCommand]:
    """Every documented command of README.md and docs/*.md, in the order of the docs."""
    found: list[DocCommand] = []
    for path in doc_files():
        doc = path.relative_to(REPO_ROOT).as_posix()
        for tag, first, body in _blocks(path.read_text()):
            if tag in COMMAND_TAGS and not any(ln.startswith("$ ") for ln in body):
                found += _command_block(doc, first, body)
            elif tag in COMMAND_TAGS or tag in TEXT_TAGS:
                found += _prompt_block(doc, first, body)
    return found


# -- comparing output with the doc's quotes ------------------------------------------------------

_TOKEN = re.compile(r"[-+]?\d+(?:\.\d+)?(?:[eE][-+]?\d+)?|[A-Za-z_]+|\S")


def _tokens(text: str) -> list[str]:
    return _TOKEN.findall(text)


def _is_number(tok: str) -> bool:
    return tok[-1].isdigit()


def half_ulp(tok: str) -> float:
    """Half a unit in the last digit the doc prints: the rounding it uses."""
    mantissa, _, exponent = tok.lower().partition("e")
    decimals = len(mantissa.partition(".")[2])
    return 0.5 * 10.0 ** (-decimals + (int(exponent) if exponent else 0))


def _same(expected: str, actual: str) -> bool:
    if _is_number(expected) and _is_number(actual):
        return abs(float(expected) - float(actual)) <= half_ulp(expected) * (1 + 1e-9)
    return expected == actual


def quoted_output_mismatch(expected: str, actual: str) -> str | None:
    """None when ``actual`` shows what the doc quotes, else a description of the first miss.

    Compared as tokens (numbers and single characters), so line wrapping and spacing in the
    doc do not matter; every number must equal the printed one within half a unit of the
    doc's last digit. A line ``...`` in the quote skips any output; otherwise each run of
    quoted lines must appear in the output as one piece, in order."""
    segments: list[list[str]] = [[]]
    for ln in expected.splitlines():
        if ln.strip() == "...":
            segments.append([])
        elif ln.strip():
            segments[-1].append(ln)
    act = _tokens(actual)
    pos = 0
    for lines in filter(None, segments):
        seg = [t for ln in lines for t in _tokens(ln)]
        hit = _find(seg, act, pos)
        if hit is None:
            missing = next((ln for ln in lines if _find(_tokens(ln), act, 0) is None), None)
            if missing is not None:
                return f"the doc quotes a line the output does not have: {missing.strip()!r}"
            return f"the doc's lines are in the output, but not together in order: {lines}"
        pos = hit + len(seg)
    return None


def _find(seg: list[str], act: list[str], start: int) -> int | None:
    n = len(seg)
    return next(
        (i for i in range(start, len(act) - n + 1) if all(map(_same, seg, act[i : i + n]))),
        None,
    )


def doc_states(doc: str, pattern: str) -> list[str]:
    """What a doc states, as printed (figures keep their digits): the groups of ``pattern``, a
    regular expression searched in the doc with its whitespace runs made one space."""
    text = " ".join((REPO_ROOT / doc).read_text().split())
    m = re.search(pattern, text)
    assert m, f"{doc} no longer states /{pattern}/"
    return list(m.groups())


def assert_as_documented(stated: list[str], values, what: str) -> None:
    """Each value equals the doc's figure within the rounding the doc prints it with."""
    values = [float(v) for v in values]
    assert len(stated) == len(values), (stated, values)
    for s, v in zip(stated, values, strict=True):
        assert abs(float(s) - v) <= half_ulp(s) * (1 + 1e-9), f"{what}: doc says {s}, got {v}"


# -- running -------------------------------------------------------------------------------------


@dataclass
class Ran:
    command: DocCommand
    returncode: int
    stdout: str
    stderr: str
    cwd: Path

    @property
    def output(self) -> str:
        return self.stderr + "\n" + self.stdout

    def describe(self) -> str:
        return (
            f"{self.command.where}: {self.command.text}\nexit {self.returncode}\n"
            f"--- stdout\n{self.stdout[-3000:]}\n--- stderr\n{self.stderr[-3000:]}"
        )


def make_workspace(root: Path, data_dir: Path | None = None) -> Path:
    """``root/repo`` laid out like a checkout (see the module docstring); returns it. Without
    ``data_dir`` only the commands are set up (no examples, docs or data)."""
    repo = root / "repo"
    repo.mkdir()
    if data_dir is not None:
        shutil.copytree(REPO_ROOT / "examples", repo / "examples")
        shutil.copytree(REPO_ROOT / "docs" / "cli", repo / "docs" / "cli")
        (root / "shared").mkdir()
        (root / "shared" / "data").symlink_to(data_dir.resolve(), target_is_directory=True)
    venv_bin = repo / ".venv" / "bin"
    venv_bin.mkdir(parents=True)
    path_bin = root / "bin"
    path_bin.mkdir()
    shims = {
        "trackflow": f'#!/bin/sh\nexec "{sys.executable}" -m trackflow.cli.main "$@"\n',
        "python": f'#!/bin/sh\nexec "{sys.executable}" "$@"\n',
    }
    for folder in (venv_bin, path_bin):
        for name, body in shims.items():
            (folder / name).write_text(body)
            (folder / name).chmod(0o755)
    return repo


def _environment(repo: Path) -> dict[str, str]:
    """The environment a documented command runs in: the trackflow under test first on the
    path, the workspace's ``bin`` on ``PATH``, no display for plots."""
    import trackflow

    env = dict(os.environ)
    src = str(Path(trackflow.__file__).resolve().parents[1])  # the trackflow under test
    env["PYTHONPATH"] = os.pathsep.join(filter(None, [src, env.get("PYTHONPATH")]))
    env["PATH"] = os.pathsep.join([str(repo.parent / "bin"), env.get("PATH", "")])
    env["MPLBACKEND"] = "Agg"
    return env


def _as_from_a_terminal() -> None:
    """In the command's process before it starts: Ctrl-C's signal as a terminal leaves it. A
    job started in the background of a script (CI, ``make test &``) inherits SIGINT ignored,
    and an ignored signal stays ignored across exec: Ctrl-C would never reach the command."""
    signal.signal(signal.SIGINT, signal.SIG_DFL)


def _start(cmd: DocCommand, repo: Path) -> subprocess.Popen:
    return subprocess.Popen(
        ["bash", "-c", cmd.text],
        cwd=repo,
        env=_environment(repo),
        stdin=subprocess.DEVNULL,
        stdout=subprocess.PIPE,
        stderr=subprocess.PIPE,
        text=True,
        start_new_session=True,  # its own process group: a timeout ends all of it
        preexec_fn=_as_from_a_terminal,
    )


def run_command(cmd: DocCommand, repo: Path, timeout: float = 300.0) -> Ran:
    """Run one documented command as written with ``bash -c`` in the workspace ``repo``."""
    proc = _start(cmd, repo)
    try:
        out, err = proc.communicate(timeout=timeout)
    except subprocess.TimeoutExpired as timed_out:
        os.killpg(proc.pid, signal.SIGKILL)
        out, err = proc.communicate()
        raise AssertionError(
            f"{cmd.where}: still running after {timeout:.0f} s: {cmd.text}\n{err[-2000:]}"
        ) from timed_out
    return Ran(cmd, proc.returncode, out, err, repo)


@dataclass
class Served(Ran):
    """A command that serves until interrupted: what it printed up to and after Ctrl-C, whether
    it became ready, the page it served (``url``, and the HTML it answered) and how it
    ended."""

    ready: bool = False
    url: str = ""
    page: str = ""


_URL = re.compile(r"http://127\.0\.0\.1:\d+/")


def serve_command(
    cmd: DocCommand, repo: Path, ready: str | None = None, timeout: float = 180.0
) -> Served:
    """Run a documented command that serves until interrupted, as a user does: start it as
    written, wait (bounded) until it prints its page's address (or, with ``ready``, a line
    matching that regular expression), fetch the page (if it printed one), then press Ctrl-C
    (SIGINT to its whole process group, as a terminal sends it) and wait (bounded) for it to
    end. Raises AssertionError when it prints neither or does not end."""
    import queue
    import threading
    import urllib.request

    proc = _start(cmd, repo)
    lines: queue.Queue = queue.Queue()
    kept = {"stdout": [], "stderr": []}

    def read(stream, name) -> None:
        for line in stream:
            kept[name].append(line)
            lines.put(line)
        lines.put(None)

    readers = [threading.Thread(target=read, args=(getattr(proc, n), n), daemon=True)
               for n in kept]  # fmt: skip
    for r in readers:
        r.start()
    wanted = _URL if ready is None else re.compile(ready)
    url, seen, ended, deadline = None, False, 0, time.monotonic() + timeout
    try:
        while not seen and ended < 2:
            try:
                line = lines.get(timeout=max(deadline - time.monotonic(), 0.0))
            except queue.Empty:
                raise AssertionError(
                    f"{cmd.where}: not ready after {timeout:.0f} s: {cmd.text}\n"
                    + "".join(kept["stderr"])[-2000:]
                ) from None
            if line is None:
                ended += 1
            elif wanted.search(line):
                seen = True
                url = m.group(0) if (m := _URL.search(line)) else None
        page = ""
        if url is not None:
            with urllib.request.urlopen(url, timeout=30) as answer:
                page = answer.read().decode("utf-8", "replace")
        if seen:
            os.killpg(proc.pid, signal.SIGINT)
        rc = proc.wait(timeout=60)
    except subprocess.TimeoutExpired as still_running:
        raise AssertionError(f"{cmd.where}: still running 60 s after Ctrl-C: {cmd.text}") from (
            still_running
        )
    finally:
        if proc.poll() is None:
            os.killpg(proc.pid, signal.SIGKILL)
            proc.wait()
        for r in readers:
            r.join(timeout=10)
    out, err = "".join(kept["stdout"]), "".join(kept["stderr"])
    return Served(cmd, rc, out, err, repo, seen, url or "", page)
