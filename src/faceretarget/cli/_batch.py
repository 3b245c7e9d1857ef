"""Command line: ``faceretarget batch``, a library of takes onto many characters on Dask.

::

    faceretarget batch JOBS.toml [--scheduler tcp://HOST:PORT | --workers N] [--resume | --no-resume]
        [--dry-run]

:func:`register` adds the command to the main parser's subparsers; the handler takes ``(args, log)``
and returns the exit code (:data:`EXIT_CODES`).  The work is :func:`faceretarget.pipelines.run_batch`.
"""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

from ._support import Range, check_inputs, run_alone

__all__ = ["register", "cmd_batch", "main", "EXIT_CODES"]

#: ``--workers``.
WORKERS = Range(1, 1024, integer=True)

#: What the exit code of ``faceretarget batch`` means (also in docs/batch.md and ``--help``).
EXIT_CODES = {
    0: "every job succeeded or was already up to date (or --dry-run)",
    1: "the batch ran but one or more jobs failed (each is in the summary and the manifest with its "
       "one-line error), or the cluster was lost before the end (run again to resume)",
    2: "nothing ran: the jobs file or the command line is wrong, an input is missing, the scheduler "
       "cannot be reached, or another batch holds the manifest",
    130: "interrupted (Ctrl-C); the jobs finished so far are in the manifest, run again to resume",
}


def cmd_batch(args, log) -> int:
    """``batch``: run (or with ``--dry-run`` plan) a jobs file and print the summary."""
    check_inputs(("JOBS.toml", args.jobs))
    log(f"reading {args.jobs}")
    from ..pipelines import read_jobs, run_batch

    spec = read_jobs(args.jobs)                # every key checked before any cluster starts
    summary = run_batch(spec, scheduler=args.scheduler, workers=args.workers, resume=args.resume,
                        dry_run=args.dry_run, progress=not log.quiet, log=log)
    if summary.dry_run:
        return 0
    if summary.ran:
        log(summary.table())
    for line in summary.warning_lines():
        log(line)
    rate = summary.ran / summary.seconds if summary.seconds > 0 else 0.0
    log(f"{summary.count('ok')} succeeded, {len(summary.failed)} failed, {summary.count('skipped')} up to date"
        f"{', ' + str(summary.count('not run')) + ' not run' if summary.count('not run') else ''} in "
        f"{summary.seconds:.1f} s ({rate:.2f} jobs/s); manifest {summary.manifest}")
    for o in summary.failed:
        print(f"failed: {o.job.id}: {o.error}", file=sys.stderr)
    return summary.exit_code


def register(subparsers) -> argparse.ArgumentParser:
    """Add ``batch`` to ``subparsers`` (from ``add_subparsers``)."""
    codes = "; ".join(f"{k} {v}" for k, v in EXIT_CODES.items())
    p = subparsers.add_parser(
        "batch", help="a library of takes onto many characters on Dask, resumable (docs/batch.md)",
        description="Run every job of a TOML jobs file (inputs by glob x characters x operation: clone, retarget, "
        "animate, headmotion-synth; output templates such as out/{character}/{take}.glb) on Dask's distributed "
        "scheduler: a local cluster sized to the machine, or --scheduler. Each character's model is fitted "
        "once and shared; every output is written atomically and recorded in the manifest (batch.jsonl), "
        "so a run skips the jobs already up to date and re-runs exactly those whose inputs, rig or options "
        "changed; a failed job does not stop the others. Needs Dask's distributed scheduler (make batch). "
        f"Exit codes: {codes}.")
    p.add_argument("jobs", type=Path, help="the jobs file (.toml; docs/batch.md)")
    where = p.add_mutually_exclusive_group()
    where.add_argument("--scheduler", metavar="tcp://HOST:PORT",
                       help="a running Dask scheduler (its workers must see the same paths)")
    where.add_argument("--workers", type=WORKERS, help=f"local worker processes, {WORKERS} (default one per core)")
    p.add_argument("--resume", action=argparse.BooleanOptionalAction, default=True,
                   help="skip the jobs the manifest shows up to date (the default); --no-resume re-runs every job")
    p.add_argument("--dry-run", action="store_true", help="check the jobs file and print what would run; "
                   "start nothing, write nothing")
    p.set_defaults(func=cmd_batch)
    return p


def main(argv=None) -> int:
    """Run ``batch`` stand-alone (``argv`` starts with ``batch``)."""
    return run_alone(register, argv)


if __name__ == "__main__":  # pragma: no cover
    sys.exit(main())
