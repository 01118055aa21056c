"""``python -m cms.fleet.bench speed INPUT [--workers 1 2 …] [--repeat R]``
``python -m cms.fleet.bench memory INPUT [--counts 1000 10000] [--workers W]``

``speed``: the fleet job's analysis of INPUT on a LocalCluster of 1, 2, …
single-threaded worker processes: the time from submitting the first task
to the last task's manifest back on the client, the workers writing their
partition files into a staging folder (the cluster's start, the trend step
and the swap into place not included), the best of R runs. Prints a
Markdown table: recordings/s, kilometres of rail per second (the runs'
measured lengths), per worker, the workers' CPU time in that run (their
processes' user and system time: what the analysis costs whatever else
the machine runs) and kilometres per CPU second, and the speed-up over
one worker.

``memory``: the job's client's peak memory against the number of
recordings. For each count N a folder of N hard links to INPUT's
recordings in turn, and the whole job (``python -m cms.fleet.job``, its
own process) run over it on a scheduler and W workers started from the
command line; the client's peak resident set (``ru_maxrss`` of its
process) and wall time, and the ratio to the first count's peak.
"""

from __future__ import annotations

import argparse
import os
import shutil
import subprocess
import sys
import tempfile
import time

from . import job, procs


def _cpu_s() -> float:
    """This process's CPU time (user and system), in seconds."""
    import resource

    u = resource.getrusage(resource.RUSAGE_SELF)
    return u.ru_utime + u.ru_stime


def measure(recordings: list, workers: int, repeat: int, options: dict) -> tuple[float, float, float]:
    """The best of ``repeat`` analyses of ``recordings`` on ``workers``
    LocalCluster workers: (seconds, the workers' CPU seconds in that run,
    kilometres measured)."""
    best = (float("inf"), 0.0)
    km = 0.0
    with job.client_for(workers, None) as client, tempfile.TemporaryDirectory(prefix="cms-fleet-bench-") as tmp:
        client.wait_for_workers(workers)
        # One task per worker first: imports and the module load on every worker.
        warm = [([recordings[0][0]], os.path.join(tmp, "warm"), i, options) for i in range(workers)]
        for _ in job.bounded(client, job.analyse_task, warm, workers):
            pass
        for k in range(repeat):
            m = job.Manifest()
            cpu0 = sum(client.run(_cpu_s).values())
            t = time.perf_counter()
            job.run(recordings, client, options, os.path.join(tmp, str(k)), workers, m)
            secs = time.perf_counter() - t
            cpu = sum(client.run(_cpu_s).values()) - cpu0
            best = min(best, (secs, cpu))
            if m.failed:
                raise SystemExit(f"error: {m.failed[0][1]}")
            km = m.measured_mm / 1e6
    return best[0], best[1], km


def speed(a: argparse.Namespace) -> int:
    recordings = job.list_recordings(a.input)
    options = {"edition": "2006", "block_m": a.block_m, "dx_mm": None, "segment_mm": 1000.0}
    size = sum(n for _, n in recordings)
    print(f"{len(recordings)} recordings, {size / 1e6:.1f} MB, {os.cpu_count()} CPUs, best of {a.repeat}\n")
    print("| workers | seconds | recordings/s | km | km/s | km/s per worker | workers' CPU s | km per CPU s | speed-up |")
    print("|---|---|---|---|---|---|---|---|---|")
    base = None
    for n in a.workers:
        s, cpu, km = measure(recordings, n, a.repeat, options)
        rate = len(recordings) / s
        base = base or rate
        print(
            f"| {n} | {s:.2f} | {rate:.1f} | {km:.3f} | {km / s:.4f} | {km / s / n:.4f} | {cpu:.2f} | {km / cpu:.4f} | {rate / base:.2f} |",
            flush=True,
        )
    return 0


def linked_fleet(sources: list[str], count: int, folder: str) -> None:
    """``count`` hard links to ``sources`` in turn, in ``folder``."""
    os.makedirs(folder)
    for k in range(count):
        os.link(sources[k % len(sources)], os.path.join(folder, f"run-{k:05d}.cmsrec"))


def memory(a: argparse.Namespace) -> int:
    sources = [u for u, _ in job.list_recordings(a.input)]
    if any("://" in u for u in sources):
        raise SystemExit("error: memory: INPUT must be a local folder (its recordings are hard-linked)")
    print(f"{len(sources)} distinct recordings of {a.input}, hard-linked; {a.workers} workers; {os.cpu_count()} CPUs\n")
    print("| recordings | client peak MB | seconds | peak / first |")
    print("|---|---|---|---|")
    first = None
    scratch = a.scratch or os.path.dirname(os.path.abspath(a.input))
    with tempfile.TemporaryDirectory(prefix=".cms-fleet-mem-", dir=scratch) as tmp:
        with procs.DaskProcesses(os.path.join(tmp, "dask"), a.workers) as cluster:
            for n in a.counts:
                fleet = os.path.join(tmp, f"fleet-{n}")
                linked_fleet(sources, n, fleet)
                out = os.path.join(tmp, f"ds-{n}")
                cmd = [sys.executable, "-m", "cms.fleet.job", fleet, out, "--scheduler", cluster.address, "--block-m", str(a.block_m)]
                t = time.perf_counter()
                p = subprocess.Popen(cmd, stdout=subprocess.DEVNULL, stderr=subprocess.PIPE)
                _, status, usage = os.wait4(p.pid, 0)
                secs = time.perf_counter() - t
                err = p.stderr.read().decode(errors="replace").strip()
                p.stderr.close()
                p.returncode = os.waitstatus_to_exitcode(status)
                if p.returncode not in (0,):
                    raise SystemExit(f"error: {' '.join(cmd)} exited with {p.returncode}: {err.splitlines()[-1] if err else ''}")
                peak_mb = usage.ru_maxrss / 1024  # kilobytes on Linux
                first = first or peak_mb
                print(f"| {n} | {peak_mb:.1f} | {secs:.1f} | {peak_mb / first:.3f} |", flush=True)
                shutil.rmtree(fleet)
                shutil.rmtree(out)
    return 0


def main(argv=None) -> int:
    p = argparse.ArgumentParser(prog="python -m cms.fleet.bench", description=__doc__.split("\n\n")[1])
    sub = p.add_subparsers(dest="what", required=True)
    s = sub.add_parser("speed", help="recordings and km of rail per second per worker")
    s.add_argument("input", metavar="INPUT")
    s.add_argument("--workers", type=int, nargs="+", default=[1, 2])
    s.add_argument("--repeat", type=int, default=3)
    s.add_argument("--block-m", type=float, default=50.0)
    m = sub.add_parser("memory", help="the client's peak memory against the number of recordings")
    m.add_argument("input", metavar="INPUT")
    m.add_argument("--counts", type=int, nargs="+", default=[1000, 10000])
    m.add_argument("--workers", type=int, default=2)
    m.add_argument("--block-m", type=float, default=50.0)
    m.add_argument("--scratch", help="where the linked fleets go (default: beside INPUT; on INPUT's filesystem, for hard links)")
    a = p.parse_args(argv)
    return speed(a) if a.what == "speed" else memory(a)


if __name__ == "__main__":
    sys.exit(main())
