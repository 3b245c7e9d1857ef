"""Where the headless-Chromium checks find node, three.js, puppeteer-core and Chromium (make tools browser),
shared by tests/test_browser.py and tests/test_live.py."""

from __future__ import annotations

import os
import shutil
from pathlib import Path

REPO = Path(__file__).resolve().parents[1]
NODE_MODULES = REPO / ".tools" / "node_modules"
THREE_DIR = Path(os.environ.get("THREE_DIR", NODE_MODULES / "three"))
PUPPETEER_DIR = Path(os.environ.get("PUPPETEER_CORE_DIR", NODE_MODULES / "puppeteer-core"))
CHROMIUM = Path(os.environ.get("CHROMIUM") or shutil.which("chromium") or "/usr/bin/chromium")


def browser_missing(what: str, *, three: bool = False) -> str | None:
    """Why ``what`` cannot run in headless Chromium (None when everything is there)."""
    if shutil.which("node") is None:
        return f"node not found: cannot run {what} (install nodejs)"
    if three and not (THREE_DIR / "package.json").is_file():
        return f"three.js not installed at {THREE_DIR}: run `make tools browser`"
    if not (PUPPETEER_DIR / "package.json").is_file():
        return f"puppeteer-core not installed at {PUPPETEER_DIR}: run `make tools browser`"
    if not CHROMIUM.is_file():
        return f"Chromium not found at {CHROMIUM}: run `make tools browser` (or set CHROMIUM)"
    return None
