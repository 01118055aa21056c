"""``python -m cms.fleet.bench INPUT [--workers 1 2 …] [--repeat R]``

Recordings per second of the fleet job's analysis over INPUT on a
LocalCluster of 1, 2, … single-threaded worker processes: the time from
submitting the recordings to holding every table back on the client (the
cluster's start and the dataset's write not included), the best of R
runs. Prints a Markdown table: recordings/s, per worker, and the speed-up
over one worker.
"""

from __future__ import annotations

import argparse
import os
import sys
import time

from . import job


def measure(urls: list, workers: int, repeat: int, options: dict) -> float:
    best = float("inf")
    with job.client_for(workers, None) as client:
        client.wait_for_workers(workers)
        # One recording first: imports and the module load on every worker.
        client.gather(client.map(job.analyse_one, urls[:workers], options=options, pure=False))
        for _ in range(repeat):
            t = time.perf_counter()
            tables = job.run(urls, client, options)
            best = min(best, time.perf_counter() - t)
            failed = [e for e in tables["runs"]["error"].to_pylist() if e]
            if failed:
                raise SystemExit(f"error: {failed[0]}")
    return best


def main(argv=None) -> int:
    p = argparse.ArgumentParser(prog="python -m cms.fleet.bench", description=__doc__.split("\n\n")[1])
    p.add_argument("input", metavar="INPUT")
    p.add_argument("--workers", type=int, nargs="+", default=[1, 2])
    p.add_argument("--repeat", type=int, default=3)
    p.add_argument("--block-m", type=float, default=50.0)
    a = p.parse_args(argv)
    urls = job.list_recordings(a.input)
    options = {"edition": "2006", "block_m": a.block_m, "dx_mm": None, "segment_mm": 1000.0}
    size = sum(os.path.getsize(u) for u in urls if "://" not in u)
    print(f"{len(urls)} recordings, {size / 1e6:.1f} MB, {os.cpu_count()} CPUs, best of {a.repeat}\n")
    print("| workers | seconds | recordings/s | per worker | speed-up |")
    print("|---|---|---|---|---|")
    base = None
    for n in a.workers:
        s = measure(urls, n, a.repeat, options)
        rate = len(urls) / s
        base = base or rate
        print(f"| {n} | {s:.2f} | {rate:.1f} | {rate / n:.1f} | {rate / base:.2f} |", flush=True)
    return 0


if __name__ == "__main__":
    sys.exit(main())
