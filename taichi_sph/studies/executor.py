"""One way to run a study's independent cases (compare, sweep, stability): each case into its own run
folder, in this process (`--jobs 1`), on a local process pool (`--jobs N`) or on a Ray cluster
(`--cluster auto|ray://HOST:PORT`).

The folders are the record: a case is finished when its summary.json says `ok` or `unstable`, and the
study's report is assembled from the folders' summaries, so `--resume` runs only the cases whose folder
lacks a finished summary. A case that raises, or whose worker process dies, comes back as status
`failed` (traceback in its error.txt) and never stops the others; a folder that says `running` with no live
process holding its lock reads `died` (run/lock.py). Before any case starts, a case folder in use by a live run
refuses the study (naming the pid), and so does output that will not fit on the disk (run/disk.py, `--force`).

Pool workers are started with 'spawn': each initialises its own Taichi runtime (a runtime must never
be forked after ti.init). Every case is the same call, `run_case(cfg, run_dir)`, whatever runs it, so
the results do not depend on the executor (on the CPU, to the last digit).
"""

from __future__ import annotations

import gc
import json
import logging
import os
import signal
import sys
import threading
import time
import traceback
from dataclasses import dataclass, replace
from pathlib import Path
from typing import Callable, Iterable

from taichi_sph.config.schema import Config
from taichi_sph.errors import EXIT_INTERRUPTED, EXIT_OK, EXIT_UNSTABLE, FolderInUse, SPHError, UsageError
from taichi_sph.run import disk
from taichi_sph.run.lock import effective_status, in_use_message, live_holder
from taichi_sph.run.output import RunFolder

FINISHED = ("ok", "unstable")
_EXIT_CODES = {"ok": EXIT_OK, "unstable": EXIT_UNSTABLE, "interrupted": EXIT_INTERRUPTED}
CLUSTER_HINT = "pip install taichi-sph[cluster]"


@dataclass(frozen=True)
class Job:
    """One case of a study: a config run into its own folder; `loop_schedule` (serial | parallel) fixes the CPU
    loop schedule for it unless TAICHI_SPH_LOOP_SCHEDULE is set (None: decided by timing, sph/schedule.py)."""

    name: str
    cfg: Config
    run_dir: Path
    render: bool = False
    loop_schedule: str | None = None


@dataclass(frozen=True)
class Dispatch:
    """How a study runs its cases: `jobs` local processes (1: in this process) or a Ray `cluster`
    ("auto" or "ray://HOST:PORT"); `resume` skips cases whose folder holds a finished summary; `force` runs
    them even when their output will not fit on the disk."""

    jobs: int = 1
    cluster: str | None = None
    resume: bool = False
    quiet: bool = True
    force: bool = False


def default_jobs(cores: int | None = None) -> int:
    """One case at a time on machines with <= 4 cores (clean timings), else one per 4 cores
    (each case's Taichi loops use several threads)."""
    cores = cores or os.cpu_count() or 1
    return 1 if cores <= 4 else cores // 4


# A step of ISPH against one of WCSPH on the same particles (its PPE's ~10 matrix-free iterations and the
# free-surface passes): `bench` on the 2D dam break, 100k particles, 4.19 against 0.86 M particle-steps/s.
ISPH_STEP_COST = 5.0


def estimated_work(cfg: Config) -> float:
    """A case's cost in particle-neighbour-steps, to start the longest cases first: (fluid + wall particles) x
    the lattice's neighbours in the kernel support x t_end / dt, dt the smallest a-priori limit (run/checks.py
    time_step_limits: Courant cfl h / (c0 + U) for WCSPH or cfl h / U for ISPH, force, viscous) or the fixed dt;
    an ISPH step counts ISPH_STEP_COST. Against the wall times of the validation report's 34 runs (one thread
    each) the log of wall / estimate spreads with a standard deviation of 1.57 (2.25 with the Courant limit alone,
    which missed the viscous step of Poiseuille flow and of ISPH's Taylor-Green vortex by up to 1000x)."""
    from taichi_sph.config.schema import AUTO
    from taichi_sph.run.checks import lattice_neighbours, time_step_limits
    from taichi_sph.run.memory import particle_counts
    fluid, wall, _ = particle_counts(cfg)
    neighbours = lattice_neighbours(cfg)
    dt = float(cfg.time.dt) if cfg.time.dt != AUTO else min(time_step_limits(cfg).values())
    return (fluid + wall) * neighbours * cfg.time.t_end / dt * (ISPH_STEP_COST if cfg.solver == "isph" else 1.0)


def longest_first(jobs: list[Job]) -> list[Job]:
    """The jobs in decreasing estimated_work (ties in their order): on a pool of N workers the last case to
    start is then a short one, not the study's longest (a validation's 3D wave or a sweep's finest spacing
    started last ran alone for minutes while the other workers idled)."""
    return sorted(jobs, key=lambda job: -estimated_work(job.cfg))


# ----------------------------------------------------------------------------- one case
def release_runtime(cfg: Config) -> None:
    """Free the fields of the run that just ended: Taichi keeps every field until ti.reset, so a
    process running dozens of cases would grow. Re-initialises with the run's arch and precision."""
    from taichi_sph.run.runtime import init_taichi, reset

    gc.collect()  # closes a renderer's GGUI window before the runtime goes
    reset()
    init_taichi(cfg.arch, cfg.precision)


def failed_summary(cfg: Config, error: str, exit_code: int = 1) -> dict:
    """The summary of a case that produced none of its own."""
    return {"scene": cfg.name, "solver": cfg.solver, "status": "failed", "exit_code": exit_code, "error": error,
            "errors": {}, "warnings": []}


def run_case(cfg: Config, out_dir: Path, *, render: bool = False, quiet: bool = True, log=None) -> dict:
    """Run one scene with one solver into `out_dir` and return its summary (the run folder: README.md).

    A run that raises comes back as {"status": "failed", "error": "..."}, written to the folder's
    summary.json, with the traceback in `out_dir/error.txt`: one broken case must not lose the others.
    """
    from taichi_sph.run.simulation import Simulation

    out_dir = Path(out_dir)
    try:
        result = Simulation(cfg, out_dir, render=render, quiet=quiet, log=log).run()
        summary = dict(result.summary)
        summary["exit_code"] = result.exit_code
    except KeyboardInterrupt:
        raise
    except Exception as e:  # noqa: BLE001 (reported in the summary, traceback kept on disk)
        message = str(e).splitlines()[0] if str(e) else ""
        summary = failed_summary(cfg, message if isinstance(e, SPHError) else f"{type(e).__name__}: {message}",
                                 getattr(e, "exit_code", 1))
        if not isinstance(e, FolderInUse):  # the folder is another run's: leave it alone
            try:
                out_dir.mkdir(parents=True, exist_ok=True)
                (out_dir / "error.txt").write_text(traceback.format_exc())
                RunFolder(out_dir).write_summary(summary)
            except OSError:  # a full disk: the run's own summary.json already says so, if it fitted
                pass
    finally:
        try:
            release_runtime(cfg)
        except SPHError:
            pass
    summary["run_dir"] = str(out_dir)
    return summary


def run_job(job: Job) -> dict:
    """The unit of work every executor sends: one case into its folder."""
    from taichi_sph.sph.schedule import schedule_unless_fixed
    with schedule_unless_fixed(job.loop_schedule):
        return run_case(job.cfg, job.run_dir, render=job.render)


# ----------------------------------------------------------------------------- the folders
def read_case(run_dir: Path) -> dict | None:
    """A case folder's summary.json with `run_dir` and `exit_code` added; None when absent or unreadable."""
    path = Path(run_dir) / "summary.json"
    try:
        summary = json.loads(path.read_text())
    except (OSError, ValueError):
        return None
    summary["run_dir"] = str(run_dir)
    summary["status"] = effective_status(run_dir, summary.get("status"))
    summary.setdefault("exit_code", _EXIT_CODES.get(summary.get("status"), 1))
    return summary


def is_finished(run_dir: Path) -> bool:
    """Does the folder hold a finished run (status ok or unstable)?"""
    s = read_case(run_dir)
    return s is not None and s.get("status") in FINISHED


def _record(job: Job, summary: dict) -> None:
    """Make sure the folder tells what happened: a case whose folder has no summary, the `running` one of
    a dead worker, or one that disagrees with what came back (a stale one), gets the returned summary; a folder
    another live run holds is left alone."""
    if live_holder(job.run_dir) is not None:
        return
    s = read_case(job.run_dir)
    if s is None or s.get("status") != summary.get("status"):
        job.run_dir.mkdir(parents=True, exist_ok=True)
        RunFolder(job.run_dir).write_summary({k: v for k, v in summary.items() if k != "run_dir"})


# ----------------------------------------------------------------------------- progress
class StudyProgress:
    """One line on stderr per finished case: done / running / failed of the total, and the ETA
    (time so far per case finished in this session, times the cases left)."""

    def __init__(self, label: str, total: int, workers: int, enabled: bool = True, clock=time.perf_counter,
                 stream=None) -> None:
        self.label, self.total, self.workers, self.enabled = label, total, workers, enabled
        self.clock, self.stream = clock, stream
        self.start = clock()
        self.done = self.failed = self.resumed = self.ran = 0

    def skip(self, n: int) -> None:
        """`n` cases were already finished (resume)."""
        self.done += n
        self.resumed += n
        if n:
            self._print(f"{n} finished case(s) kept from a previous run")

    def finish(self, name: str, status: str) -> None:
        self.done += 1
        self.ran += 1
        self.failed += status == "failed"
        self._print(f"{name}: {status}")

    def line(self) -> str:
        left = self.total - self.done
        running = min(self.workers, left)
        eta = ""
        if self.ran and left:
            eta = f", ETA {_duration((self.clock() - self.start) / self.ran * left)}"
        return f"{self.done}/{self.total} done, {running} running, {self.failed} failed{eta}"

    def _print(self, what: str) -> None:
        if self.enabled:
            print(f"{self.label}: {what}; {self.line()}", file=self.stream or sys.stderr, flush=True)


def _duration(seconds: float) -> str:
    s = int(round(seconds))
    return f"{s // 60}m{s % 60:02d}s" if s >= 60 else f"{s}s"


# ----------------------------------------------------------------------------- executors
def _serial(jobs: list[Job], done: Callable[[Job, dict], None]) -> None:
    """In this process, one after the other; an interrupted case stops the study."""
    for job in jobs:
        summary = run_job(job)
        done(job, summary)
        if summary.get("status") == "interrupted":
            break


class _StopOnInterrupt:
    """While a pool runs: Ctrl-C reaches the workers too (same process group), each of which checkpoints
    its case and reports it `interrupted`; here it only stops new cases from starting."""

    def __init__(self) -> None:
        self.stopped = False
        self._previous = None

    def __enter__(self) -> "_StopOnInterrupt":
        if threading.current_thread() is threading.main_thread():
            self._previous = signal.signal(signal.SIGINT, self._stop)
        return self

    def _stop(self, *_args) -> None:
        self.stopped = True

    def __exit__(self, *exc: object) -> None:
        if self._previous is not None:
            signal.signal(signal.SIGINT, self._previous)


def worker_threads(workers: int, cores: int | None = None) -> int:
    """Taichi CPU threads per pool worker: the machine's cores shared out, at least one. With every worker at
    Taichi's default (a thread per core) the threads of one parallel loop wait on each other across workers."""
    cores = cores or os.cpu_count() or 1
    return max(1, cores // max(1, workers))


def _share_cores(threads: int) -> None:
    """A pool worker's initializer: its Taichi runtime's CPU threads (TI_CPU_MAX_NUM_THREADS, read by ti.init),
    unless the user's environment sets them."""
    os.environ.setdefault("TI_CPU_MAX_NUM_THREADS", str(threads))


def _pool(jobs: list[Job], workers: int, done: Callable[[Job, dict], None]) -> None:
    """A local pool of spawned processes. A dead worker breaks the pool: the cases it held are tried
    once more on a fresh pool, then reported failed. After Ctrl-C (or a case that reports itself
    interrupted) no new case starts; the running ones finish as `interrupted`."""
    import multiprocessing
    from concurrent.futures import CancelledError, ProcessPoolExecutor, as_completed
    from concurrent.futures.process import BrokenProcessPool

    tries = {job.name: 0 for job in jobs}
    pending = list(jobs)
    with _StopOnInterrupt() as interrupt:
        while pending and not interrupt.stopped:
            retry: list[Job] = []
            context = multiprocessing.get_context("spawn")
            n = min(workers, len(pending))
            with ProcessPoolExecutor(n, mp_context=context, initializer=_share_cores,
                                     initargs=(worker_threads(n),)) as pool:
                futures = {pool.submit(run_job, job): job for job in pending}
                for fut in as_completed(futures):
                    job = futures[fut]
                    try:
                        summary = fut.result()
                    except CancelledError:
                        continue
                    except KeyboardInterrupt:  # Ctrl-C reached the worker outside a run's own handler
                        summary = {"scene": job.cfg.name, "solver": job.cfg.solver, "status": "interrupted",
                                   "exit_code": EXIT_INTERRUPTED, "errors": {}, "warnings": []}
                    except BrokenProcessPool:
                        tries[job.name] += 1
                        if interrupt.stopped:
                            continue
                        if tries[job.name] < 2:
                            retry.append(job)
                            continue
                        summary = failed_summary(job.cfg, "the worker process died (killed, or crashed inside Taichi)")
                    except Exception as e:  # noqa: BLE001 (the case failed, not the study)
                        summary = failed_summary(job.cfg, f"{type(e).__name__}: {e}")
                    done(job, summary)
                    if summary.get("status") == "interrupted":
                        interrupt.stopped = True
                    if interrupt.stopped:
                        for f in futures:
                            f.cancel()
            pending = retry


def _import_ray():
    try:
        import ray
    except ImportError:
        raise UsageError(f"--cluster needs Ray, which is not installed: {CLUSTER_HINT}") from None
    return ray


def ray_resources(cfg: Config) -> dict:
    """What one case asks of the cluster: one GPU on a GPU arch, else one CPU."""
    return {"num_gpus": 1} if cfg.arch in ("cuda", "gpu", "vulkan") else {"num_cpus": 1}


def _ray(jobs: list[Job], address: str, done: Callable[[Job, dict], None]) -> None:
    """Each case a Ray task. Uses a Ray already initialised in this process, else connects to `address`
    ("auto": the cluster `ray start` runs on this machine). Run folders must be on a shared filesystem;
    a case whose folder is not visible here gets the summary its task returned."""
    ray = _import_ray()
    started = not ray.is_initialized()
    if started:
        try:
            ray.init(address=address, log_to_driver=False, logging_level=logging.WARNING)
        except (ConnectionError, RuntimeError, ValueError) as e:
            raise UsageError(f"--cluster {address}: cannot connect to Ray: {str(e).splitlines()[0]}") from None
    try:
        task = ray.remote(run_job)
        # a Ray worker's working directory is not this one: send absolute run folders
        refs = {task.options(**ray_resources(job.cfg)).remote(replace(job, run_dir=job.run_dir.resolve())): job
                for job in jobs}
        waiting = list(refs)
        try:
            while waiting:
                ready, waiting = ray.wait(waiting, num_returns=1)
                job = refs[ready[0]]
                try:
                    summary = ray.get(ready[0])
                except Exception as e:  # noqa: BLE001 (a task or worker that died: the case failed)
                    summary = failed_summary(job.cfg, f"Ray task failed: {str(e).splitlines()[0]}")
                done(job, summary)
        except KeyboardInterrupt:
            for ref in waiting:  # the cluster's tasks do not see this Ctrl-C: stop them
                ray.cancel(ref, force=True)
            raise
    finally:
        if started:
            ray.shutdown()


def check_dispatch(dispatch: Dispatch) -> None:
    """Refuse a bad --jobs / --cluster before anything runs."""
    if dispatch.jobs < 1:
        raise UsageError(f"--jobs must be >= 1, got {dispatch.jobs}")
    if dispatch.cluster is not None:
        c = dispatch.cluster
        if c != "auto" and not c.startswith("ray://"):
            raise UsageError(f"--cluster expects 'auto' or 'ray://HOST:PORT', got '{c}'")
        _import_ray()


def dispatch_from_args(args) -> Dispatch:
    """--jobs / --cluster / --resume / --quiet of a study command, checked."""
    jobs = args.jobs if getattr(args, "jobs", None) is not None else default_jobs()
    dispatch = Dispatch(jobs=jobs, cluster=getattr(args, "cluster", None), resume=getattr(args, "resume", False),
                        quiet=getattr(args, "quiet", False), force=getattr(args, "force", False))
    if dispatch.cluster is not None and getattr(args, "jobs", None) is not None:
        raise UsageError("--jobs and --cluster exclude each other (the cluster decides how many cases run at once)")
    check_dispatch(dispatch)
    return dispatch


def check_folders(jobs: list[Job], *, force: bool = False) -> None:
    """Refuse a study before any case starts: a case folder a live run holds (FolderInUse, naming the pid),
    or output that will not fit on the disk, summed over the cases (PreflightError unless `force`)."""
    for job in jobs:
        holder = live_holder(job.run_dir)
        if holder is not None:
            raise FolderInUse(f"case {job.name}: " + in_use_message(job.run_dir, holder))
    if jobs:
        disk.preflight([(job.cfg, job.run_dir, job.render) for job in jobs], force=force)


def run_cases(jobs: Iterable[Job], dispatch: Dispatch = Dispatch(), label: str = "study") -> dict[str, dict]:
    """Run every job not already finished (with `resume`), each into its folder; return name -> the
    summary read back from its folder, in the jobs' order (cases not reached, after an interrupted
    one, are left out)."""
    jobs = list(jobs)
    names = [j.name for j in jobs]
    if len(set(names)) != len(names):
        raise ValueError(f"case names must be unique: {names}")
    check_dispatch(dispatch)
    todo = [j for j in jobs if not (dispatch.resume and is_finished(j.run_dir))]
    check_folders(todo, force=dispatch.force)
    reached = {j.name for j in jobs} - {j.name for j in todo}
    workers = max(1, len(todo) if dispatch.cluster else min(dispatch.jobs, len(todo)))
    progress = StudyProgress(label, len(jobs), workers, enabled=not dispatch.quiet)
    progress.skip(len(reached))

    def done(job: Job, summary: dict) -> None:
        _record(job, summary)
        reached.add(job.name)
        progress.finish(job.name, summary.get("status", "?"))

    if not todo:
        pass
    elif dispatch.cluster is not None:
        _ray(longest_first(todo), dispatch.cluster, done)
    elif dispatch.jobs == 1 or len(todo) == 1:
        _serial(todo, done)
    else:
        _pool(longest_first(todo), dispatch.jobs, done)
    summaries = {j.name: read_case(j.run_dir) for j in jobs if j.name in reached}
    return {name: s for name, s in summaries.items() if s is not None}
