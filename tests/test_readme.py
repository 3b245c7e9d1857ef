"""The README runs as written (issue 24): every shell block, in order, in a scratch folder, after the set-up
that ``make test`` has just done, with only the substitutions ``bench/readme.py`` declares (this checkout's
``faceretarget`` command first on PATH; ``../shared/data`` the data folder).  Nothing it prints looks like a
failure, and no command is silent for long.  The README is a front page: under 200 lines, and every local
link in it exists.
"""

from __future__ import annotations

import re
import sys
from pathlib import Path

import pytest

REPO = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(REPO / "bench"))

import readme as readme_runner  # noqa: E402

README = REPO / "README.md"
#: Seconds a README command may print nothing (progress bars count).  The goal is 2 s on a quiet machine
#: (bench/readme.py measures it: 1.2-1.7 s); the test allows for a loaded machine (4.9 s at load 9 on 2 cores)
#: and catches what it is for: tens of seconds of silence.
MAX_SILENCE = 6.0


def test_readme_is_a_front_page_and_its_links_exist():
    text = README.read_text(encoding="utf-8")
    assert len(text.splitlines()) < 200
    links = re.findall(r"\]\((?!https?://|#)([^)#\s]+)", text)
    assert links and not [p for p in links if not (REPO / p).exists()]
    blocks = readme_runner.shell_blocks(README)
    assert blocks[0].setup and "make demo" in blocks[0].text and "make test" in blocks[0].text
    assert ". .venv/bin/activate" in blocks[0].text                   # how to reach the command
    assert "animate" in blocks[1].text and "--character" in blocks[1].text   # the main job comes first


# slow: every README command as a user runs it (video capture, previews, Blender, shape generation): ~50 s; it is the README's contract
def test_every_readme_block_runs_as_written(data_dir, tmp_path):
    lines: list[str] = []
    results = readme_runner.run_page(README, str(data_dir.resolve()), tmp_path, log=lines.append)
    print("\n".join(lines))
    blocks = [b for b in readme_runner.shell_blocks(README) if not b.setup]
    assert len(results) == len(blocks) >= 4, lines
    for r in results:
        assert r.returncode == 0, f"README line {r.line}: exit {r.returncode}\n{r.output[-3000:]}"
        assert not r.alarming, f"README line {r.line}: {r.alarming}"
        assert r.longest_silence < MAX_SILENCE, f"README line {r.line}: silent {r.longest_silence:.1f} s after " \
                                                f"{r.silence_after!r}"
    # what the main job promised is there
    for name in ("katie.glb", "katie.wav", "katie_preview.mp4", "check.png", "s07_on_arkit.csv", "s07_on_arkit.blend",
                 "jaw_keys/contact_sheet.png", "cheeks_through_jaw_keys.glb", "head_db.npz", "head.bvh",
                 "aian_arkit.glb", "aian_arkit_sheet.png", "katie_arkit.glb"):
        assert (tmp_path / name).is_file() and (tmp_path / name).stat().st_size > 0, name


@pytest.mark.parametrize("text,setup", [("make demo\nmake test\n", True), ("# a comment\nmake docs\n", True),
                                        ("faceretarget demo\n", False)])
def test_the_setup_block_is_the_one_that_starts_with_make(text, setup):
    assert readme_runner.Block(1, text).setup is setup
