"""Resumable episode jobs: run a picklable function over many work items in local processes or on Ray.

Used by demonstration collection and evaluation. Each job has a unique key; the driver skips jobs
already done (per a caller's ``is_done``), runs the rest in ``spawn``-started worker processes (one
torch thread and one llvmpipe thread each: forking after EGL or torch can hang) or as Ray tasks on an
existing cluster, and hands each result to ``on_result`` in the driver, which writes it atomically.
A killed run therefore loses at most the jobs in flight; rerunning the same command resumes.
Local workers watch their parent and exit as soon as it is gone, so killing the driver (even with
``kill -9``) leaves no worker, and then no resource tracker, behind. Ray tasks die with their driver
through Ray's own job lifetime: the driver's ``ray.init`` makes it a Ray job, the tasks are that job's
(plain tasks, no detached actors), and when the driver process ends — also by ``kill -9`` — Ray marks
the job finished and every node's raylet kills the job's worker processes, running tasks included
(a few seconds on one node; tested). With ``--ray-address local`` the driver starts a cluster of its
own, which ends with it. A driver that stops with an error cancels its pending and running tasks.

Failure injection for tests, through the one hook :func:`fail_point`: with ``NUE_FAIL_AFTER=k`` in the
environment, the driver raises :class:`InjectedFailure` after k results were written in this run (as if
the job were killed); training uses the same hook (``NUE_FAIL_AT_STEP``).
"""

from __future__ import annotations

import multiprocessing as mp
import os
import threading
import time
import zlib
from concurrent.futures import FIRST_COMPLETED, Future, ProcessPoolExecutor, wait
from queue import Empty
from dataclasses import dataclass
from typing import Any, Callable, Iterable, Sequence, TypeVar

import numpy as np
from tqdm import tqdm

FAIL_AFTER_ENV = "NUE_FAIL_AFTER"
T = TypeVar("T")


class InjectedFailure(RuntimeError):
    """Raised on purpose (``NUE_FAIL_AFTER``, ``NUE_FAIL_AT_STEP``) to test that interrupted jobs resume."""


def fail_point(env_var: str, count: int, what: str) -> None:
    """Test hook: raise :class:`InjectedFailure` once ``count`` reaches the positive integer in the environment
    variable ``env_var`` (unset or 0: never), as if the process were killed right after ``what``."""
    limit = int(os.environ.get(env_var, "0") or 0)
    if limit and count >= limit:
        raise InjectedFailure(f"{env_var}={limit}: stopping after {what}")


_WORKER_OBJECTS: dict = {}


def worker_cached(key: tuple, build: Callable[[], T]) -> T:
    """``build()`` once per process and ``key`` (scenes, envs, policies, memories a worker reuses across jobs)."""
    if key not in _WORKER_OBJECTS:
        _WORKER_OBJECTS[key] = build()
    return _WORKER_OBJECTS[key]


def episode_seed(seed: int, scene: str, episode_id: str) -> int:
    """Per-episode seed, stable across processes (CRC32, never Python's hash())."""
    return int(np.random.SeedSequence([seed, zlib.crc32(f"{scene}/{episode_id}".encode())]).generate_state(1)[0])


@dataclass(frozen=True)
class Job:
    """One unit of work: ``key`` names its output (unique, file-safe); ``payload`` is what the worker needs,
    a picklable value (a frozen dataclass such as ``EvalJob`` or ``CollectJob``)."""

    key: str
    """Unique, file-safe name of the job's output."""
    payload: Any = None
    """The worker's input, pickled to it as it is."""


PARENT_POLL_S = 0.2
"""How often a local worker checks that its parent is alive, seconds."""


def watch_parent(parent_pid: int, interval: float = PARENT_POLL_S) -> threading.Thread:
    """Exit this process (status 1, no cleanup) once its parent ``parent_pid`` has gone: an orphan is
    re-parented, so ``os.getppid()`` changes. Runs in a daemon thread, so it also fires while the
    worker's main thread is busy with a job."""

    def watch() -> None:
        while os.getppid() == parent_pid:
            time.sleep(interval)
        os._exit(1)

    thread = threading.Thread(target=watch, name="nue-parent-watch", daemon=True)
    thread.start()
    return thread


def worker_init(threads: int = 1, parent_pid: int | None = None) -> None:
    """Initialise a worker process: one torch / BLAS / llvmpipe thread unless told otherwise; with
    ``parent_pid``, exit when that parent dies (:func:`watch_parent`)."""
    if parent_pid is not None:
        watch_parent(parent_pid)
    for var in ("LP_NUM_THREADS", "OMP_NUM_THREADS", "MKL_NUM_THREADS"):
        os.environ[var] = str(threads)
    try:
        import torch

        torch.set_num_threads(threads)
    except ImportError:  # pragma: no cover
        pass


def _call(fn, job):
    return job.key, fn(job)


def _call_in_process(fn, job):
    """Run one job in this process with one torch thread, as a worker would (:func:`worker_init`), and
    restore the caller's thread count. A record must not depend on ``--workers``: with two intra-op
    threads the reductions round differently and a closed-loop episode drifts apart within a few hundred
    steps (measured: val_00 easy_000 of the v6 NUE ended 3.1 m vs 7.1 m from the goal)."""
    import torch

    threads = torch.get_num_threads()
    torch.set_num_threads(1)
    try:
        return fn(job)
    finally:
        torch.set_num_threads(threads)


def run_jobs(
    jobs: Sequence[Job],
    fn: Callable[[Job], Any],
    on_result: Callable[[Job, Any], None],
    is_done: Callable[[Job], bool] = lambda job: False,
    workers: int = 1,
    ray_address: str | None = None,
    desc: str = "episodes",
    progress: bool = True,
    stream: bool = False,
    total: int | None = None,
) -> int:
    """Run ``fn`` over the jobs not yet done; returns the number of results handed to ``on_result`` in this call.

    ``fn`` must be a module-level function (it is pickled to workers). ``on_result(job, result)`` runs
    in the driver, in completion order. ``workers <= 1`` without Ray runs in this process. Every job runs
    with one torch thread wherever it runs, so results do not depend on ``workers`` or Ray.

    ``stream``: ``fn(job)`` yields several results (e.g. the episodes of a lock-step batch); each reaches
    ``on_result`` as soon as the worker yields it (a local worker's queue, a Ray streaming generator), so a
    killed run loses only the results not yet yielded. ``total``: the progress bar's count of results
    (default one per job).
    """
    todo = [j for j in jobs if not is_done(j)]
    keys = [j.key for j in jobs]
    if len(set(keys)) != len(keys):
        raise ValueError("job keys must be unique")
    n_total = len(jobs) if total is None else total
    bar = tqdm(total=n_total, initial=n_total - len(todo) if total is None else 0, desc=desc, unit="ep",
               disable=not progress, dynamic_ncols=True, smoothing=0.1)
    written = 0

    def finish(job: Job, result: Any) -> None:
        nonlocal written
        on_result(job, result)
        written += 1
        bar.update(1)
        fail_point(FAIL_AFTER_ENV, written, f"{written} results")

    by_key = {j.key: j for j in todo}
    try:
        if ray_address:
            _run_ray(todo, fn, finish, ray_address, stream)
        elif workers <= 1:
            for job in todo:
                if stream:
                    _stream_in_process(fn, job, finish)
                else:
                    finish(job, _call_in_process(fn, job))
        else:
            _run_pool(todo, fn, finish, workers, by_key, stream)
    finally:
        bar.close()
    return written


def _stream_in_process(fn, job: Job, finish) -> None:
    """A streaming job in this process with one torch thread (as :func:`_call_in_process`): each result is
    finished as soon as ``fn`` yields it."""
    import torch

    threads = torch.get_num_threads()
    torch.set_num_threads(1)
    try:
        for result in fn(job):
            finish(job, result)
    finally:
        torch.set_num_threads(threads)


_STREAM_QUEUE: Any = None


def _stream_worker_init(threads: int, parent_pid: int, queue) -> None:
    """A local worker of streaming jobs: :func:`worker_init` and the queue its results go back by."""
    global _STREAM_QUEUE
    _STREAM_QUEUE = queue
    worker_init(threads, parent_pid)


def _call_stream(fn, job):
    """Worker: put each result of ``fn(job)`` on the queue at once; returns the key and how many were put."""
    n = 0
    for result in fn(job):
        _STREAM_QUEUE.put((job.key, result))
        n += 1
    return job.key, n


def _run_pool(todo: Iterable[Job], fn, finish, workers: int, by_key: dict[str, Job], stream: bool = False) -> None:
    ctx = mp.get_context("spawn")
    pending_jobs = list(todo)
    queue: Any = ctx.Queue() if stream else None
    init: Any = _stream_worker_init if stream else worker_init
    initargs: Any = (1, os.getpid(), queue) if stream else (1, os.getpid())
    with ProcessPoolExecutor(max_workers=workers, mp_context=ctx, initializer=init, initargs=initargs) as pool:
        running: set[Future] = set()
        received: dict[str, int] = {}

        def take(block: bool) -> None:  # one streamed result, if any
            try:
                key, result = queue.get(timeout=0.05) if block else queue.get_nowait()
            except Empty:
                return
            received[key] = received.get(key, 0) + 1
            finish(by_key[key], result)

        try:
            # Keep at most 2 jobs per worker queued, so a kill loses little and results stream in order.
            while pending_jobs or running:
                while pending_jobs and len(running) < 2 * workers:
                    running.add(pool.submit(_call_stream if stream else _call, fn, pending_jobs.pop(0)))
                if stream:
                    take(block=True)
                    done = {f for f in running if f.done()}
                    running -= done
                else:
                    done, running = wait(running, return_when=FIRST_COMPLETED)
                for fut in done:
                    key, result = fut.result()
                    if not stream:
                        finish(by_key[key], result)
                        continue
                    while received.get(key, 0) < result:  # the queue's feeder may trail the job's end
                        take(block=True)
        except BaseException:
            for f in running:
                f.cancel()
            raise


def _run_ray(todo: Sequence[Job], fn, finish, address: str, stream: bool = False) -> None:
    try:
        import ray
    except ImportError:
        raise RuntimeError("--ray-address needs Ray: pip install 'nue[ray]'") from None
    if not ray.is_initialized():
        ray.init(address=address, ignore_reinit_error=True, log_to_driver=False)
    if stream:
        _run_ray_stream(ray, todo, fn, finish)
        return
    remote = ray.remote(num_cpus=1)(_ray_call)
    refs = {remote.remote(fn, job): job for job in todo}  # tasks of this driver's job: they end with it
    try:
        while refs:
            ready, _ = ray.wait(list(refs), num_returns=1)
            for ref in ready:
                job = refs.pop(ref)
                finish(job, ray.get(ref)[1])
    except BaseException:
        for ref in refs:
            ray.cancel(ref, force=True)
        raise


def _ray_call(fn, job):
    worker_init(1)
    return _call(fn, job)


def _run_ray_stream(ray, todo: Sequence[Job], fn, finish) -> None:
    """Streaming jobs as Ray generator tasks: each result is finished as soon as its task yields it."""
    remote = ray.remote(num_cpus=1)(_ray_stream)
    gens = {remote.remote(fn, job): job for job in todo}
    try:
        while gens:
            ready, _ = ray.wait(list(gens), num_returns=1)
            for gen in ready:
                try:
                    ref = next(gen)
                except StopIteration:
                    del gens[gen]
                    continue
                finish(gens[gen], ray.get(ref))
    except BaseException:
        for gen in gens:
            ray.cancel(gen, force=True)
        raise


def _ray_stream(fn, job):
    worker_init(1)
    yield from fn(job)


