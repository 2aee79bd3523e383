#!/usr/bin/env python3
"""Python at native speed (issue 18): what driving the filters from Python costs.

1. Crossing overhead of the per-step path: ``predict`` + ``update`` + ``pose`` called from a
   Python loop on arrays already made, against the batch call on the same arrays, per scan.
   Empty scans on an empty map (``--micro-steps``), so that the filter's own work is nearly
   nil and the difference is the crossing; and Victoria Park's real scans on D&C.
2. Victoria Park end to end (every step, the joins still queued and the final estimate): the
   batch call ``slam.run(vp)`` and the README's loop over ``vp.steps`` against
   ``dcslam_bench vp`` run in the same process tree, alternately, ``--repeats`` times.
3. The floor: one call of a compiled method that does nothing (the ``next_fresh_id`` getter of
   the compiled EKF), the least a crossing costs on this machine; a scan makes three.

Parts 1 and 3 print the fastest of ``--repeats`` runs (loop and batch alternately; the
overhead is the fastest loop minus the fastest batch call); part 2 prints medians, and its
ratios are of medians. Usage:

    .venv/bin/python benchmarks/python_native.py --bench build/dev/benchmarks/dcslam_bench
    .venv/bin/python benchmarks/python_native.py --parts crossing   # parts 1 and 3 only
"""

from __future__ import annotations

import argparse
import json
import os
import statistics
import subprocess
import tempfile
import time

import numpy as np

import dcslam


def native_total(bench: str, filter_name: str) -> float:
    with tempfile.TemporaryDirectory() as folder:
        path = os.path.join(folder, "vp.json")
        subprocess.run([bench, "vp", "--filter", filter_name, "--json", path], check=True, stdout=subprocess.DEVNULL)
        with open(path) as file:
            (run,) = json.load(file)["runs"]
    return float(run["total_seconds"])


def make_filter(filter_name: str, config: dcslam.SlamConfig) -> dcslam.slam.SlamFilter:
    return dcslam.DCSlam(config) if filter_name == "dc" else dcslam.EkfSlam(config)


def finish(slam) -> None:
    if isinstance(slam, dcslam.DCSlam):
        slam.finish_joins()
    slam.estimate()


def batch_total(vp, filter_name: str) -> float:
    slam = make_filter(filter_name, vp.slam_config())
    start = time.perf_counter()
    slam.run(vp)
    finish(slam)
    return time.perf_counter() - start


def readme_loop_total(vp, filter_name: str) -> float:
    slam = make_filter(filter_name, vp.slam_config())
    start = time.perf_counter()
    for s in vp.steps:
        slam.predict(s.u, s.Q)
        slam.update(s.z, s.R)
        slam.pose()
    finish(slam)
    return time.perf_counter() - start


def crossing_overhead(slam_factory, u, Q, z, R, offsets, repeats: int) -> float:
    """Seconds per scan that the loop of step calls costs beyond the batch call: the fastest of
    ``repeats`` loops minus the fastest of as many batch calls, run alternately (on a loaded
    machine other work only adds time, so the minimum is the figure least disturbed by it)."""
    loops, batches = zip(*(loop_and_batch(slam_factory, u, Q, z, R, offsets) for _ in range(repeats)))
    return (min(loops) - min(batches)) / len(u)


def loop_and_batch(slam_factory, u, Q, z, R, offsets):
    """Seconds of the loop of step calls and of the batch call over the same steps."""
    rows = [(u[k], Q[k] if Q.ndim == 3 else Q, z[offsets[k]:offsets[k + 1]],
             R[offsets[k]:offsets[k + 1]] if R.ndim == 3 else R) for k in range(len(u))]
    looped = slam_factory()
    start = time.perf_counter()
    for uk, Qk, zk, Rk in rows:
        looped.predict(uk, Qk)
        looped.update(zk, Rk)
        looped.pose()
    loop_seconds = time.perf_counter() - start
    batched = slam_factory()
    start = time.perf_counter()
    batched.run_batch(u, Q, z, R, offsets)
    batch_seconds = time.perf_counter() - start
    return loop_seconds, batch_seconds


def empty_crossing(calls: int) -> float:
    """Seconds a call of a compiled method that does nothing costs, loop included."""
    core = dcslam.EkfSlam(dcslam.SlamConfig())._core
    start = time.perf_counter()
    for _ in range(calls):
        core.next_fresh_id
    return (time.perf_counter() - start) / calls


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--bench", default="build/dev/benchmarks/dcslam_bench")
    parser.add_argument("--repeats", type=int, default=5)
    parser.add_argument("--micro-steps", type=int, default=100_000)
    parser.add_argument("--filters", default="dc,ekf")
    parser.add_argument("--parts", default="crossing,vp", help="crossing (parts 1 and 3), vp (part 2), or both")
    args = parser.parse_args()
    parts = set(args.parts.split(","))

    vp = dcslam.datasets.victoria_park()
    if "crossing" in parts:
        n = args.micro_steps
        empty = dict(u=np.zeros((n, 3)), Q=np.eye(3) * 1e-4, z=np.zeros((0, 2)), R=np.eye(2) * 1e-2,
                     offsets=np.zeros(n + 1, dtype=np.int64))
        micro = crossing_overhead(lambda: dcslam.EkfSlam(dcslam.SlamConfig()), **empty, repeats=args.repeats)
        print(f"crossing overhead, empty scans, EkfSlam: {micro * 1e6:.2f} us a scan "
              f"(predict + update + pose; fastest of {args.repeats} each)")
        floor = min(empty_crossing(n) for _ in range(args.repeats))
        print(f"floor: an empty compiled call {floor * 1e9:.0f} ns, three a scan {3 * floor * 1e6:.2f} us")
        arrays = dict(u=vp.u, Q=vp.Q, z=vp.z, R=vp.R, offsets=vp.offsets)
        real = crossing_overhead(lambda: dcslam.DCSlam(vp.slam_config()), **arrays, repeats=args.repeats)
        print(f"crossing overhead, Victoria Park scans, DCSlam: {real * 1e6:.2f} us a scan")
    if "vp" not in parts:
        return

    totals = {}
    for filter_name in args.filters.split(","):
        native, batch, loop = [], [], []
        for _ in range(args.repeats):
            native.append(native_total(args.bench, filter_name))
            batch.append(batch_total(vp, filter_name))
            loop.append(readme_loop_total(vp, filter_name))
        totals[filter_name] = {name: statistics.median(values) for name, values in
                               (("native", native), ("batch", batch), ("loop", loop))}
        t = totals[filter_name]
        print(f"Victoria Park {filter_name}: dcslam_bench vp {t['native']:.3f} s, batch call {t['batch']:.3f} s "
              f"({t['batch'] / t['native']:.2f}x), README loop {t['loop']:.3f} s ({t['loop'] / t['native']:.2f}x)")
    if {"dc", "ekf"} <= set(totals):
        for kind in ("native", "batch", "loop"):
            print(f"EKF/D&C total ratio, {kind}: {totals['ekf'][kind] / totals['dc'][kind]:.1f}x")


if __name__ == "__main__":
    main()
