"""Where the pipeline's independent jobs run: processes of this machine (``local``) or tasks of a Ray cluster
(``ray``), chosen by ``pipeline.executor`` in params.yaml or a command's ``--executor``.

A job is a module-level function applied to a small picklable description (a training cell, an evaluation, an
Optuna trial's values). Each job starts by setting its own process-wide state (``learn.process.training_process``), so a
job computes the same bytes in a fresh local process as in a Ray worker; ``tests/core/test_executor.py`` checks that a
training matrix through a local Ray runtime gives the local executor's curves and actors.

With ``ray``, ``ray.init()`` joins the cluster named by ``RAY_ADDRESS`` or starts a local runtime; every node
needs this package installed (``pip install '.[ray]'``), since the jobs are its functions.
"""

from __future__ import annotations

import logging
import multiprocessing
import os
from collections.abc import Callable, Iterable

from replicate.core.progress import bar as progress_bar
from replicate.core.progress import log_lines
from replicate.core.schema import ConfigError

log = logging.getLogger(__name__)

EXECUTORS = ("local", "ray")


def check_executor(name: str) -> str:
    if name not in EXECUTORS:
        raise ConfigError(f"executor must be one of {', '.join(EXECUTORS)}, got {name!r} (pipeline.executor in "
                          "params.yaml, or --executor)")
    return name


def configured_executor(params, requested: str | None = None) -> str:
    """``requested`` (a command's ``--executor``) or else params.yaml's ``pipeline.executor`` (default local)."""
    return check_executor(requested or params.stages.get("pipeline", {}).get("executor", "local"))


def map_jobs(fn: Callable, jobs: Iterable, executor: str = "local", workers: int = 1,
             progress: str | None = None) -> list:
    """``[fn(job) for job in jobs]``, in the order of ``jobs``: with ``local`` in ``workers`` processes of this
    machine, with ``ray`` as one Ray task of one CPU per job (the cluster's CPUs set how many run at once).
    ``progress`` names a bar of the jobs done (a command's; the pipeline's stages show none). An error or Ctrl-C
    stops the workers at once: the local pool is terminated, Ray's tasks are cancelled."""
    jobs = list(jobs)
    bar = progress_bar(progress is not None, total=len(jobs), desc=progress or "jobs", unit="job", leave=False)
    with bar:
        if check_executor(executor) == "ray":
            ray = ray_runtime()
            task = ray.remote(num_cpus=1, max_retries=0)(apply)
            refs = [task.remote(fn, job) for job in jobs]
            try:
                pending = list(refs)
                while pending:
                    done, pending = ray.wait(pending, num_returns=1)
                    bar.update(len(done))
                return ray.get(refs)
            except BaseException:
                for ref in refs:
                    ray.cancel(ref, force=True)
                raise
        # the workers' own phases stay quiet in a log: the jobs' count here speaks for them
        pool = multiprocessing.Pool(max(1, workers), initializer=log_lines, initargs=(False,))
        try:
            results = []
            for result in pool.imap(fn, jobs):
                results.append(result)
                bar.update()
            pool.close()
            return results
        except BaseException:
            pool.terminate()  # the workers stop now, whatever they were doing
            raise
        finally:
            pool.join()


def apply(fn: Callable, job):
    """One job, as a Ray task runs it (``fn`` may be a ``functools.partial``, which ``ray.remote`` refuses)."""
    return fn(job)


def ray_runtime(num_cpus: int | None = None, attempts: int = 3):
    """The Ray module, initialised: the cluster at ``RAY_ADDRESS`` if set, else a local runtime of ``num_cpus``
    (default: this machine's cores), without a dashboard.

    A local raylet gives its agents 15 s to report their ports and dies when they miss it ("the current node
    timed out during startup", ray-project/ray#65983); starting five Python helpers took longer than that on this
    2-core machine while it trained. A start that times out so is tried again, ``attempts`` times in all."""
    try:
        import ray
    except ImportError as exc:
        raise ConfigError("the ray executor needs Ray: pip install '.[ray]' (or use the local executor)") from exc
    if ray.is_initialized():
        return ray
    if os.environ.get("RAY_ADDRESS"):
        ray.init(log_to_driver=False)
        return ray
    for attempt in range(1, attempts + 1):
        try:
            ray.init(num_cpus=num_cpus, include_dashboard=False, log_to_driver=False)
            return ray
        except Exception as exc:
            if "timed out during startup" not in str(exc) or attempt == attempts:
                raise
            ray.shutdown()
            log.warning("Ray's local runtime did not start in time (attempt %d of %d); trying again", attempt,
                        attempts)
    return ray


def parallel_slots(executor: str, workers: int) -> int:
    """How many jobs run at once: ``workers`` locally, the cluster's CPUs with Ray."""
    if check_executor(executor) == "ray":
        return max(1, int(ray_runtime().cluster_resources().get("CPU", 1)))
    return max(1, workers)


class Beside:
    """``fn()`` computed in a forked process while this one goes on (a command's second core); ``result()`` waits
    for it and returns its value or raises its error. Forked: ``fn`` may be a closure, and nothing is imported
    again."""

    def __init__(self, fn: Callable[[], object]):
        context = multiprocessing.get_context("fork")
        self.receive, send = context.Pipe(duplex=False)

        def run() -> None:
            try:
                send.send((True, fn()))
            except BaseException as exc:  # noqa: BLE001 - handed to the parent, which raises it
                send.send((False, exc))

        self.process = context.Process(target=run, daemon=True)
        self.process.start()
        send.close()

    def result(self):
        try:
            ok, value = self.receive.recv()
        except EOFError:
            raise RuntimeError(f"the process beside this one ended without a result (exit code "
                               f"{self.process.exitcode})") from None
        finally:
            self.process.join()
        if not ok:
            raise value
        return value

