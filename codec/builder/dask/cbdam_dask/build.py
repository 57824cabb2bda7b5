"""`python -m cbdam_dask build`: a sharded cbdam build whose steps are Dask tasks.

The steps are the `cbdam shard` subcommands (docs/SHARDING.md), each run by a task as a
subprocess of a Dask worker: plan with the apex (reads the inputs once), one task per shard,
merge. Planets too: `--planet` and the planet's flags go to `cbdam shard plan` as any flag
does, and the steps are the same. They share a work directory, which must be a path every worker reaches (a shared file system or an
object-store mount), as must the inputs and the output. Dask does the scheduling: tasks are
submitted with `retries=`, and a task whose worker dies is rerun elsewhere; every step is
idempotent, so a rerun is harmless.
"""

import argparse
import os
import shutil
import signal
import subprocess
import sys
import time


class StepFailed(Exception):
    """A cbdam step that failed with a message (bad input or arguments): not worth a retry."""


def _kill_hook():
    """For tests only: with CBDAM_DASK_TEST_KILL_ONCE=FILE, the first shard task to find FILE
    absent creates it and, once its cbdam subprocess has run a moment, kills that and its own
    worker process (SIGKILL), as a machine lost mid-build would."""
    marker = os.environ.get("CBDAM_DASK_TEST_KILL_ONCE")
    if not marker:
        return False
    try:
        fd = os.open(marker, os.O_CREAT | os.O_EXCL | os.O_WRONLY)
    except FileExistsError:
        return False
    os.write(fd, str(os.getpid()).encode())
    os.close(fd)
    return True


def run_step(cbdam, args, kill_hook=False):
    """Runs `cbdam shard ARGS...`; returns ("ok", its stdout). A failure with a message (exit 1 or 2)
    comes back as ("error", message) so that it is reported once, not retried; anything else (a
    signal, a missing binary) raises, and Dask retries the task."""
    command = [cbdam, "shard", *args]
    if kill_hook and _kill_hook():
        child = subprocess.Popen(command, stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL)
        time.sleep(0.1)
        child.kill()
        os.kill(os.getpid(), signal.SIGKILL)
    done = subprocess.run(command, capture_output=True, text=True)
    return _finish_step(command, done.returncode, done.stdout, done.stderr)


def _finish_step(command, returncode, stdout, stderr):
    """`run_step`'s reading of a finished `cbdam shard` step: ("ok", stdout) or ("error", message)
    for a failure with a message (exit 1 or 2); raises on anything else."""
    if returncode in (1, 2):
        return ("error", f"{' '.join(command)}: {stderr.strip()}")
    if returncode != 0:
        raise RuntimeError(
            f"{' '.join(command)} ended with status {returncode}: {stderr.strip()}"
        )
    return ("ok", stdout.strip())


def _absolute_input(text):
    """An input as `cbdam build` takes it, made absolute: workers may run elsewhere."""
    if text.startswith("@"):
        return "@" + os.path.abspath(text[1:])
    return os.path.abspath(text)


def _parse(argv):
    p = argparse.ArgumentParser(
        prog="python -m cbdam_dask",
        allow_abbrev=False,
        description="Sharded cbdam builds on Dask distributed. Flags not listed here go to "
        "`cbdam shard plan` as they go to `cbdam build` (e.g. --diamond-size, --memory-limit).",
    )
    sub = p.add_subparsers(dest="command", required=True)
    # No abbreviations: a `cbdam build` flag must reach `cbdam shard plan` as written.
    b = sub.add_parser("build", help="build a repository with a Dask cluster", allow_abbrev=False)
    b.add_argument("inputs", nargs="+", help="DEM files, directories, globs, @LIST or VRTs")
    b.add_argument("-o", "--output", required=True, help="the repository to write")
    b.add_argument("--max-error", required=True, help="guaranteed maximum error, metres")
    b.add_argument(
        "--scheduler",
        required=True,
        help="local:WORKERS (a LocalCluster of worker processes) or tcp://HOST:PORT",
    )
    b.add_argument("--cbdam", default="cbdam", help="the cbdam binary (default: on PATH)")
    b.add_argument(
        "--work", help="work directory on a shared path (default: OUTPUT.shards beside it)"
    )
    b.add_argument(
        "--shards",
        type=int,
        help="shards (default: one per worker; a retried shard keeps the blocks it finished, so "
        "more only balance uneven workers, at a read of the apex field each)",
    )
    b.add_argument("--retries", type=int, default=3, help="Dask retries per task")
    b.add_argument(
        "--threads",
        type=int,
        help="threads per shard task (default: cores / workers with local:, all with tcp://)",
    )
    b.add_argument("--keep-work", action="store_true", help="keep the work directory")
    return p.parse_known_args(argv)


class Progress:
    """One bar with ETA on a terminal; one line per finished shard otherwise."""

    def __init__(self, total):
        self.total, self.done, self.start = total, 0, time.monotonic()
        self.tty = sys.stderr.isatty()

    def shard(self, line):
        self.done += 1
        elapsed = time.monotonic() - self.start
        eta = elapsed / self.done * (self.total - self.done)
        if self.tty:
            width = 30
            full = width * self.done // self.total
            sys.stderr.write(
                f"\rshards [{'#' * full}{'.' * (width - full)}] {self.done}/{self.total}, "
                f"{elapsed:.0f} s elapsed, ETA {eta:.0f} s "
            )
            if self.done == self.total:
                sys.stderr.write("\n")
        else:
            sys.stderr.write(f"[{self.done}/{self.total}] {line} (ETA {eta:.0f} s)\n")
        sys.stderr.flush()


def _quiet_local_workers():
    """A local cluster's workers only wait on `cbdam shard` subprocesses, so their dashboard
    aids (the statistical profiler sampling every thread's stack each 10 ms, the system and
    memory monitors every 0.5 s) would cost CPU beside the build for nothing: about 0.08 CPU-s
    per second of build, measured (docs/RESULTS.md, "The Dask build's overhead"). Off or slowed
    here, for `local:` only; a `tcp://` cluster keeps its own configuration."""
    import dask

    dask.config.set({
        "distributed.worker.profile.enabled": False,
        "distributed.admin.system-monitor.interval": "5s",
        "distributed.worker.memory.monitor-interval": "5s",
        "distributed.admin.tick.interval": "1s",
    })


def main(argv):
    args, extra = _parse(argv)
    cbdam = shutil.which(args.cbdam) or args.cbdam
    if not os.path.exists(cbdam):
        print(f"cbdam_dask: error: the cbdam binary {args.cbdam!r} is not found", file=sys.stderr)
        return 1
    cbdam = os.path.abspath(cbdam)
    output = os.path.abspath(args.output)
    work = os.path.abspath(args.work or output + ".shards")

    started = time.monotonic()

    def plan_args(workers):
        return ["plan", *map(_absolute_input, args.inputs), "-o", output,
                "--max-error", args.max_error, "--work", work,
                "--shards", str(args.shards or workers), "--apex", *extra]

    early_plan = None
    if args.scheduler.startswith("local:"):
        try:
            workers = int(args.scheduler[len("local:"):])
        except ValueError:
            workers = 0
        if workers < 1:
            print(f"cbdam_dask: error: --scheduler {args.scheduler}: expected local:WORKERS",
                  file=sys.stderr)
            return 2
        # A local cluster runs on this machine: the plan starts here at once, while Dask is
        # imported and the cluster starts (about 2 s), instead of as the first task after.
        command = [cbdam, "shard", *plan_args(workers)]
        early_plan = (command, subprocess.Popen(command, stdout=subprocess.PIPE,
                                                stderr=subprocess.PIPE, text=True))

    # Imported here: `--help` and argument errors need no Dask.
    from dask.distributed import Client, LocalCluster, as_completed

    if early_plan is not None:
        _quiet_local_workers()
        cluster = LocalCluster(
            n_workers=workers,
            threads_per_worker=1,
            processes=True,
            dashboard_address=None,
        )
        client = Client(cluster)
        threads = args.threads or max(1, (os.cpu_count() or 1) // workers)
    elif args.scheduler.startswith("tcp://"):
        cluster = None
        client = Client(args.scheduler)
        workers = max(1, len(client.scheduler_info().get("workers", {})))
        threads = args.threads
    else:
        print(f"cbdam_dask: error: --scheduler {args.scheduler}: expected local:WORKERS or "
              "tcp://HOST:PORT", file=sys.stderr)
        return 2
    print(f"cbdam_dask: {workers} workers ready in {time.monotonic() - started:.1f} s",
          file=sys.stderr)

    def step(name, step_args, kill_hook=False):
        return client.submit(run_step, cbdam, step_args, kill_hook, retries=args.retries,
                             pure=False, key=f"cbdam-{name}")

    def result(future):
        status, text = future.result()
        if status == "error":
            raise StepFailed(text)
        return text

    try:
        import json

        if early_plan is not None:
            command, process = early_plan
            stdout, stderr = process.communicate()
            try:
                status, text = _finish_step(command, process.returncode, stdout, stderr)
            except RuntimeError as e:  # no Dask task to retry here
                raise StepFailed(str(e))
            if status == "error":
                raise StepFailed(text)
        else:
            text = result(step("plan", plan_args(workers)))
        plan = json.loads(text)
        shards = plan["shards"]
        print(f"cbdam_dask: planned {shards} shards of {plan['blocks']} blocks in {work} and "
              "encoded the apex", file=sys.stderr)
        thread_args = ["--threads", str(threads)] if threads else []
        futures = [
            step(f"shard-{i}", ["run", "--work", work, "--shard", str(i), *thread_args],
                 kill_hook=True)
            for i in range(shards)
        ]
        progress = Progress(shards)
        for future in as_completed(futures):
            progress.shard(result(future))
        merged = result(step("merge", ["merge", "--work", work]))
        print(merged)
    except StepFailed as e:
        print(f"cbdam_dask: error: {e}", file=sys.stderr)
        return 1
    finally:
        client.close()
        if cluster is not None:
            cluster.close()
    if not args.keep_work:
        shutil.rmtree(work, ignore_errors=True)
    print(f"cbdam_dask: done in {time.monotonic() - started:.1f} s", file=sys.stderr)
    return 0
