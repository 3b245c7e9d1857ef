"""Memory and time of long takes: clone and retarget 10k / 30k / 60k frames (issue 11, item 6).

The shared Live Link Face take S07-001 is repeated (timecodes continuing) to 10,000, 30,000 and
60,000 frames (60,840 frames is 34 minutes at 30 fps), then every command runs in a fresh process
exactly as a user types it, writing a ``.glb``:

* ``clone`` ICT -> ARKit and ARKit -> ICT, ``rom-40`` keys from ``alex_rom_3`` (the README's quick
  start, and the same onto the 9,409-vertex ICT face);
* ``retarget`` of the take through the two rigs' own shapes, both directions.

Each run's peak resident memory is read from the kernel (``wait4``'s ``ru_maxrss`` of that process),
its wall time per 1,000 frames measured around it (the fastest of ``--repeat`` runs, 5 by
default: a run of a few seconds varies by about 0.3 s between repeats; the largest peak RSS of
them); the interpreter's own start-up (``faceretarget --version``, measured in the same run) is
reported beside it.  A run's time is a fixed part
(start-up, reading the rigs, fitting the keys) plus a part per frame, so ``s_per_kframe`` falls with
length; linearity is judged on the part per frame: ``linear`` is, per command, the cost per 1,000
frames between the two longest takes over that between the two shortest (1 = linear).  Targets:
peak RSS <= 2,000 MB at every length, ``linear`` <= 1.5.

Usage::

    python bench/scale.py [--json] [--frames 10000,30000,60000] [--repeat 3] [--data ../shared/data]

With ``--json`` the last line of stdout is ``{"runs": [{"command", "frames", "peak_rss_mb",
"s_per_kframe", "seconds"}, ...], "startup_s", "startup_rss_mb", "target_mb", "max_peak_rss_mb",
"marginal_s_per_kframe", "linear"}``.
"""

from __future__ import annotations

import argparse
import json
import os
import shutil
import subprocess
import sys
import tempfile
import time
import warnings
from pathlib import Path

REPO = Path(__file__).resolve().parents[1]
EXE = Path(sys.executable).with_name("faceretarget")


def long_take(src: Path, frames: int, out: Path) -> Path:
    """``src`` (a Live Link Face CSV) repeated to ``frames`` frames, timecodes continuing."""
    import numpy as np

    from faceretarget.io import read_livelinkface, write_livelinkface
    from faceretarget.performance import Performance

    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        take, info = read_livelinkface(src, with_info=True)
    reps = -(-frames // take.n_frames)
    step = float(np.median(np.diff(take.times)))
    span = take.times[-1] + step
    times = np.concatenate([take.times + k * span for k in range(reps)])[:frames]
    W = np.tile(take.weights, (reps, 1))[:frames]
    perf = Performance(times, take.fps, weights=W, names=take.names, source=str(out))
    return write_livelinkface(out, perf, rate=info.timecode_rate)


def measure(cmd: list[str]) -> tuple[float, float, int]:
    """(seconds, peak RSS in MB, return code) of one command in a fresh process."""
    t0 = time.perf_counter()
    p = subprocess.Popen(cmd, stdout=subprocess.DEVNULL, stderr=subprocess.PIPE)
    _, status, usage = os.wait4(p.pid, 0)
    dt = time.perf_counter() - t0
    err = p.stderr.read().decode(errors="replace") if p.stderr else ""
    rc = os.waitstatus_to_exitcode(status)
    if rc != 0:
        print(f"  failed ({rc}): {' '.join(cmd)}\n  {err.strip()[-400:]}", file=sys.stderr)
    return dt, usage.ru_maxrss / 1024.0, rc


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--data", type=Path, default=REPO.parent / "shared" / "data")
    ap.add_argument("--frames", default="10000,30000,60000")
    ap.add_argument("--repeat", type=int, default=5,
                    help="runs per command and length: the fastest time and the largest peak RSS are kept")
    ap.add_argument("--json", action="store_true")
    args = ap.parse_args(argv)
    d = args.data
    lengths = [int(x) for x in args.frames.split(",")]
    tmp = Path(tempfile.mkdtemp(prefix="faceretarget-scale-"))
    try:
        t_start, rss_start, _ = min((measure([str(EXE), "--version"]) for _ in range(3)), key=lambda r: r[0])
        print(f"start-up (faceretarget --version): {t_start:.2f} s, {rss_start:.0f} MB")
        ict, ark = d / "ict-face", d / "arkit-face"
        rom = d / "livelinkface" / "alex_rom_3.csv"
        jobs = {
            "clone ict->arkit": lambda take, out: ["clone", "--source-rig", str(ict), "--target-rig", str(ark),
                                                   "--keys", "rom-40", "--keys-from", str(rom), "--performance",
                                                   str(take), "--out", str(out)],
            "clone arkit->ict": lambda take, out: ["clone", "--source-rig", str(ark), "--target-rig", str(ict),
                                                   "--keys", "rom-40", "--keys-from", str(rom), "--performance",
                                                   str(take), "--out", str(out)],
            "retarget ict->arkit": lambda take, out: ["retarget", "--performance", str(take), "--source-keys",
                                                      str(ict), "--target-keys", str(ark), "--out", str(out)],
            "retarget arkit->ict": lambda take, out: ["retarget", "--performance", str(take), "--source-keys",
                                                      str(ark), "--target-keys", str(ict), "--out", str(out)],
        }
        runs = []
        print(f"{'command':22s} {'frames':>7s} {'peak RSS MB':>12s} {'s / 1k frames':>14s} {'seconds':>8s}")
        for n in lengths:
            take = long_take(d / "livelinkface" / "S07-001.csv", n, tmp / f"take_{n}.csv")
            for name, make in jobs.items():
                out = tmp / "out.glb"
                tries = [measure([str(EXE), "-q"] + make(take, out)) for _ in range(max(args.repeat, 1))]
                dt = min(t[0] for t in tries)
                rss = max(t[1] for t in tries)
                rc = next((t[2] for t in tries if t[2] != 0), 0)
                row = {"command": name, "frames": n, "peak_rss_mb": round(rss, 1),
                       "s_per_kframe": round(dt / n * 1000.0, 4), "seconds": round(dt, 2), "ok": rc == 0}
                runs.append(row)
                print(f"{name:22s} {n:7d} {rss:12.0f} {row['s_per_kframe']:14.3f} {dt:8.1f}" + ("" if rc == 0 else "  FAILED"))
                out.unlink(missing_ok=True)
        linear, marginal = {}, {}
        for name in jobs:
            r = sorted((x["frames"], x["seconds"]) for x in runs if x["command"] == name)
            if len(r) > 1:
                first = (r[1][1] - r[0][1]) / (r[1][0] - r[0][0]) * 1000.0
                last = (r[-1][1] - r[-2][1]) / (r[-1][0] - r[-2][0]) * 1000.0
                marginal[name] = round(last, 4)
                linear[name] = round(last / first, 3) if first > 0 else None
        worst = max(x["peak_rss_mb"] for x in runs)
        print(f"largest peak RSS {worst:.0f} MB (target <= 2000); seconds per 1k more frames (longest pair) "
              + ", ".join(f"{k} {v:.3f}" for k, v in marginal.items())
              + "; over the shortest pair's: " + ", ".join(f"{k} {v}x" for k, v in linear.items()))
        res = {"runs": runs, "startup_s": round(t_start, 3), "startup_rss_mb": round(rss_start, 1),
               "target_mb": 2000, "max_peak_rss_mb": worst, "marginal_s_per_kframe": marginal, "linear": linear}
    finally:
        shutil.rmtree(tmp, ignore_errors=True)
    if args.json:
        print(json.dumps(res))
    return 0


if __name__ == "__main__":
    sys.exit(main())
