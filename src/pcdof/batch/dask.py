"""A batch's frames on an existing ``dask.distributed`` cluster.

The job is scattered to every worker once (``broadcast=True``). Workers read inputs and write
outputs themselves, so input and output paths must resolve to the same files on every worker (a
shared filesystem, or a cluster on this machine); only the small per-frame records travel back.
"""

from __future__ import annotations

import uuid

from ..errors import InputError
from .tasks import BatchJob, FrameTask, failed_record

#: Seconds to wait for a Dask scheduler to answer.
DASK_CONNECT_TIMEOUT_S = 30


def _connect(scheduler):
    """(client, whether this call made it) for a scheduler address or an existing client."""
    try:
        from distributed import Client
    except ImportError:  # pragma: no cover - a declared dependency
        raise InputError("--scheduler needs the 'distributed' package (pip install distributed)") from None
    if isinstance(scheduler, Client):
        return scheduler, False
    try:
        return Client(scheduler, timeout=f"{DASK_CONNECT_TIMEOUT_S}s"), True
    except (OSError, TimeoutError, ValueError) as err:
        raise InputError(f"cannot connect to the Dask scheduler at {scheduler!r} (--scheduler): {err}") from None


def run_dask(job: BatchJob, tasks: list[FrameTask], scheduler, collect, render) -> None:
    """The same tasks on a Dask distributed cluster (workers write outputs to the shared filesystem).

    *render(job, task) -> record* renders one frame (:func:`pcdof.batch.runner.render_frame`).
    """
    client, own = _connect(scheduler)
    from distributed import as_completed

    try:
        job_future = client.scatter(job, broadcast=True, hash=False)
        token = uuid.uuid4().hex[:8]
        futures = {}
        for task in tasks:
            fut = client.submit(render, job_future, task, key=f"pcdof-frame-{task.index:06d}-{token}", pure=False)
            futures[fut] = task
        for fut in as_completed(futures):
            task = futures[fut]
            try:
                rec = fut.result()
            except Exception as err:  # noqa: BLE001 - e.g. KilledWorker: record it and go on
                rec = failed_record(task, job.output_dir, f"worker failed: {type(err).__name__}: {err}")
            collect(rec)
            fut.release()
    finally:
        if own:
            client.close()
