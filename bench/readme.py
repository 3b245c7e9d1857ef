"""Run the shell blocks of a Markdown page as a newcomer would (issue 24): README.md by default.

Every fenced ``sh`` block runs in order, in one scratch folder (files an earlier block writes are
there for the later ones), each through ``bash -e -o pipefail``, with only these substitutions,
declared here:

* the set-up block (its first command is ``make``: ``make demo`` / ``make test`` and
  ``. .venv/bin/activate``) is not run: CI's ``make test`` has just done it, and the scratch folder
  is not a checkout;
* ``faceretarget`` is this checkout's command: a script first on ``PATH`` running
  ``python -m faceretarget.cli`` with this interpreter and ``src/`` on ``PYTHONPATH`` (what
  ``. .venv/bin/activate`` gives after ``make demo``);
* ``../shared/data`` is the data folder (``--data``; the README's paths are relative to the checkout's
  root, and the blocks run elsewhere).

For each block: the exit code, the seconds, the longest silence (seconds without a byte of output,
progress bars included, from the start to the end) and every output line that looks like a failure
(``ERROR``, a traceback, a deprecation warning).  ``--json`` prints one JSON object as the last line.

Usage::

    python bench/readme.py [--file README.md] [--data ../shared/data] [--keep DIR] [--keep-going] [--json]
"""

from __future__ import annotations

import argparse
import json
import os
import re
import subprocess
import sys
import tempfile
import time
from dataclasses import asdict, dataclass, field
from pathlib import Path

REPO = Path(__file__).resolve().parents[1]
DATA = "../shared/data"
#: Output that looks like a failure to a newcomer.
ALARMING = re.compile(r"\bERROR\b|Traceback \(most recent call last\)|DeprecationWarning|FutureWarning|"
                      r"BuildBackendWarning|SetuptoolsDeprecationWarning")


@dataclass
class Block:
    """A fenced ``sh`` block: its first line number in the page and its text."""

    line: int
    text: str

    @property
    def setup(self) -> bool:
        first = next((ln.strip() for ln in self.text.splitlines() if ln.strip() and not ln.strip().startswith("#")), "")
        return first.startswith("make ")


@dataclass
class Result:
    line: int
    command: str
    returncode: int
    seconds: float
    longest_silence: float
    silence_after: str = ""
    alarming: list = field(default_factory=list)
    output: str = ""


def shell_blocks(page: Path) -> list[Block]:
    """The page's fenced ``sh`` / ``bash`` / ``shell`` blocks, in order."""
    blocks, cur, start = [], None, 0
    for i, line in enumerate(page.read_text(encoding="utf-8").splitlines(), 1):
        fence = line.strip()
        if cur is None and re.fullmatch(r"```(sh|bash|shell)", fence):
            cur, start = [], i + 1
        elif cur is not None and fence == "```":
            blocks.append(Block(start, "\n".join(cur) + "\n"))
            cur = None
        elif cur is not None:
            cur.append(line)
    return blocks


def command_env(bindir: Path) -> dict:
    """The environment of the blocks: this checkout's ``faceretarget`` first on ``PATH``."""
    bindir.mkdir(parents=True, exist_ok=True)
    shim = bindir / "faceretarget"
    shim.write_text(f'#!/bin/sh\nexec "{sys.executable}" -m faceretarget.cli "$@"\n')
    shim.chmod(0o755)
    env = dict(os.environ)
    env["PATH"] = os.pathsep.join([str(bindir), str(Path(sys.executable).parent), env.get("PATH", "")])
    env["PYTHONPATH"] = os.pathsep.join([str(REPO / "src")] + ([env["PYTHONPATH"]] if env.get("PYTHONPATH") else []))
    env.pop("FACERETARGET_REQUIRE_DATA", None)
    return env


def run_block(block: Block, cwd: Path, env: dict, data: str) -> Result:
    """Run one block; time it and its longest silence."""
    text = block.text.replace(DATA, data)
    t0 = time.monotonic()
    last, worst, where = t0, 0.0, "(the start)"
    chunks = []
    p = subprocess.Popen(["bash", "-e", "-o", "pipefail", "-c", text], cwd=cwd, env=env, stdin=subprocess.DEVNULL,
                         stdout=subprocess.PIPE, stderr=subprocess.STDOUT)
    while True:
        chunk = os.read(p.stdout.fileno(), 65536)          # blocks until output or the end
        now = time.monotonic()
        if not chunk:
            break
        if now - last > worst:
            worst, where = now - last, _tail(chunks)
        last = now
        chunks.append(chunk)
    p.wait()
    end = time.monotonic()
    if end - last > worst:
        worst, where = end - last, "(the end) " + _tail(chunks)
    out = b"".join(chunks).decode("utf-8", "replace")
    bad = [ln for ln in out.replace("\r", "\n").splitlines() if ALARMING.search(ln)]
    first = next((ln for ln in block.text.splitlines() if ln.strip() and not ln.startswith("#")), "")
    return Result(block.line, first.strip()[:90], p.returncode, end - t0, worst, where, bad, out)


def _tail(chunks: list[bytes]) -> str:
    """The last line printed so far (where a silence starts)."""
    text = b"".join(chunks[-4:]).decode("utf-8", "replace").replace("\r", "\n").rstrip()
    return text.rsplit("\n", 1)[-1][-100:] if text else "(the start)"


def run_page(page: Path, data: str, workdir: Path, log=print, keep_going: bool = False) -> list[Result]:
    """Every block of ``page`` but the set-up, in order, in ``workdir``; stops at the first failure unless
    ``keep_going``."""
    env = command_env(workdir / ".bin")
    results = []
    for b in shell_blocks(page):
        if b.setup:
            log(f"line {b.line}: the set-up block (make ...): done by make test, not run here")
            continue
        r = run_block(b, workdir, env, data)
        results.append(r)
        log(f"line {r.line}: exit {r.returncode}, {r.seconds:.1f} s, longest silence {r.longest_silence:.2f} s "
            f"after {r.silence_after!r}"
            f"{', ' + str(len(r.alarming)) + ' alarming line(s)' if r.alarming else ''}: {r.command}")
        if r.returncode != 0:
            log(r.output[-3000:])
            if not keep_going:
                break
    return results


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--file", default=str(REPO / "README.md"))
    ap.add_argument("--data", default=str(REPO.parent / "shared" / "data"))
    ap.add_argument("--keep", help="run in this folder (kept) instead of a temporary one")
    ap.add_argument("--keep-going", action="store_true", help="run the blocks after a failing one too")
    ap.add_argument("--json", action="store_true", help="print a JSON summary as the last line")
    a = ap.parse_args(argv)
    with tempfile.TemporaryDirectory(prefix="readme.") as tmp:
        work = Path(a.keep) if a.keep else Path(tmp)
        work.mkdir(parents=True, exist_ok=True)
        results = run_page(Path(a.file), str(Path(a.data).resolve()), work, keep_going=a.keep_going)
    ok = all(r.returncode == 0 and not r.alarming for r in results)
    worst = max(results, key=lambda r: r.longest_silence) if results else None
    print(f"{len(results)} blocks, {sum(r.seconds for r in results):.1f} s; "
          f"{'all ran cleanly' if ok else 'FAILED'}"
          + (f"; longest silence {worst.longest_silence:.2f} s (line {worst.line})" if worst else ""))
    if a.json:
        print(json.dumps({"file": a.file, "ok": ok, "blocks": [{k: v for k, v in asdict(r).items() if k != "output"}
                                                               for r in results]}))
    return 0 if ok else 1


if __name__ == "__main__":
    sys.exit(main())
