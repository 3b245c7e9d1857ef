"""Batch, the part of :mod:`faceretarget.pipelines` behind ``faceretarget batch``: a TOML jobs file
(:func:`read_jobs`, in ``_jobs.py``; checked and expanded into one :class:`Job` per take and character, without
Dask) run on Dask's distributed scheduler by :func:`run_batch` (``_run.py``), each model fitted once and
handed to the jobs that use it, every finished job one line of a resumable manifest (:func:`read_manifest`),
on an existing cluster or a :func:`local_cluster`.  Dask is imported only when a batch runs (docs/batch.md).
Everything here is also importable from :mod:`faceretarget.pipelines`.
"""

from ._jobs import JOB_OPTIONS, OPERATIONS, BatchSpec, Job, read_jobs
from ._run import (
    CONNECT_TIMEOUT,
    BatchSummary,
    ClusterError,
    JobOutcome,
    local_cluster,
    read_manifest,
    run_batch,
)

__all__ = ["run_batch", "CONNECT_TIMEOUT", "read_jobs", "read_manifest", "local_cluster", "BatchSpec", "BatchSummary",
    "Job", "JobOutcome", "ClusterError", "OPERATIONS", "JOB_OPTIONS"]
