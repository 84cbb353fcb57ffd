"""Campaign throughput: the same tasks serially and on a 2-worker LocalCluster, in one run.

    python experiments/campaign_throughput.py [--tasks 8] [--steps 4000] [--workers 2] [--repeat 3]
    python experiments/campaign_throughput.py --tasks 2 --steps 30 --workers 1 --repeat 1

Each task is one pH closed loop (DAQP, N = 5, measurement noise, its own seed) of about a
second. Both runners are warmed up first (imports, compiled kernels), so the figures compare
steady-state throughput; the cluster start is reported separately (paid once per campaign).
Serial and Dask runs alternate ``--repeat`` times (the machine's load drifts); printed per
pair and summarized (ratio of the best wall times, median ratio):

* ``throughput ratio`` = serial wall time / Dask wall time (target >= 1.8 with 2 workers);
* ``scheduling overhead`` = worker time between tasks (the wait for the first task and the
  gaps between consecutive ones: dispatch, transfer, deserialization) / task time, from the
  ``started_at`` / ``finished_at`` stamps of each task (target < 5 % for tasks >= 1 s);
* ``tail idle`` = worker time idle at the end, waiting for the last task (load imbalance of
  a few tasks on few workers, not scheduling), and ``all non-task time`` = (Dask wall time x
  workers - task time) / task time: everything together (client, writing files included);
* ``task slowdown`` = mean task time on the workers / mean task time serially: contention
  for the cores (other processes on the machine), not scheduling.
"""

from __future__ import annotations

import argparse
import itertools
import json
import os
import tempfile
import time
from dataclasses import replace
from pathlib import Path
from typing import Any


def build_parser() -> argparse.ArgumentParser:
    """The command line (``--help`` answers before the library and Dask are imported)."""
    parser = argparse.ArgumentParser(
        description=__doc__.split("\n\n")[0],
        epilog='Figures: docs/benchmarks.md, "Campaign throughput".',
    )
    parser.add_argument("--tasks", type=int, default=8, help="closed loops (8)")
    parser.add_argument("--steps", type=int, default=4000, help="samples per closed loop (4000)")
    parser.add_argument("--workers", type=int, default=2, help="Dask workers (2)")
    parser.add_argument("--solver", default="daqp")
    parser.add_argument(
        "--repeat", type=int, default=3, help="serial/Dask pairs, alternated (default 3)"
    )
    parser.add_argument("--json", type=Path, default=None, help="also write the figures here")
    return parser


if __name__ == "__main__":
    build_parser().parse_args()  # --help and bad options answer here, before the imports

from ltv_lstm_mpc.campaign import CampaignSpec, parse_spec, run_campaign, run_task  # noqa: E402

#: Row columns that hold times or the worker (they differ between the two runs).
UNTIMED = {
    "wall_s",
    "setup_s",
    "median_step_s",
    "p95_step_s",
    "max_step_s",
    "median_mpc_s",
    "started_at",
    "finished_at",
    "worker",
}


def _spec(tasks: int, steps: int, solver: str) -> CampaignSpec:
    return parse_spec(
        {
            "campaign": {
                "name": "throughput",
                "plant": "ph",
                "steps": steps,
                "setpoints": [7.5, 6.8, 8.0],
                "q2": [0.55, 0.7],
                "solver": solver,
                "noise_std": 0.01,
            },
            "factors": {"seed": list(range(tasks))},
        }
    )


def _dispatch(rows: list[dict[str, Any]], submitted: float, workers: int) -> tuple[float, float]:
    """Worker time lost to scheduling, and worker time idle at the end, s.

    Per worker: the wait for its first task plus the gaps between its consecutive tasks,
    each task lasting from ``started_at`` to ``finished_at`` (stamped by
    :func:`~ltv_lstm_mpc.campaign.task.execute`); the tail is the time each worker waits
    for the last task of the campaign to finish.
    """
    by_worker: dict[str, list[dict[str, Any]]] = {}
    for row in rows:
        by_worker.setdefault(row["worker"], []).append(row)
    end = max(row["finished_at"] for row in rows)
    lost = tail = 0.0
    for runs in by_worker.values():
        runs.sort(key=lambda r: r["started_at"])
        lost += runs[0]["started_at"] - submitted
        lost += sum(b["started_at"] - a["finished_at"] for a, b in itertools.pairwise(runs))
        tail += end - runs[-1]["finished_at"]
    tail += (workers - len(by_worker)) * (end - submitted)  # workers that got no task
    return lost, tail


def _untimed(rows: list[dict[str, Any]]) -> list[dict[str, Any]]:
    return [{k: v for k, v in row.items() if k not in UNTIMED} for row in rows]


def _measure(spec: CampaignSpec, root: Path, address: str, workers: int) -> dict[str, Any]:
    """One serial run and one Dask run of the same tasks, side by side."""
    start = time.perf_counter()
    serial = run_campaign(spec, root / "serial", serial=True, progress=False, report=False)
    serial_wall = time.perf_counter() - start
    start, submitted = time.perf_counter(), time.time()
    dask = run_campaign(spec, root / "dask", scheduler=address, progress=False, report=False)
    dask_wall = time.perf_counter() - start
    serial_tasks = sum(r["wall_s"] for r in serial.rows)
    dask_tasks = sum(r["finished_at"] - r["started_at"] for r in dask.rows)
    lost, tail = _dispatch(dask.rows, submitted, workers)
    return {
        "mean_task_s_serial": serial_tasks / len(serial.rows),
        "mean_task_s_workers": dask_tasks / len(dask.rows),
        "serial_wall_s": serial_wall,
        "dask_wall_s": dask_wall,
        "throughput_ratio": serial_wall / dask_wall,
        "scheduling_overhead_pct": 100 * lost / dask_tasks,
        "tail_idle_pct": 100 * tail / dask_tasks,
        "non_task_pct": 100 * (dask_wall * workers - dask_tasks) / dask_tasks,
        "task_slowdown": dask_tasks / serial_tasks,
        "same_results": _untimed(serial.rows) == _untimed(dask.rows),
        "errors": serial.errors + dask.errors,
    }


def main() -> int:
    args = build_parser().parse_args()

    from distributed import Client, LocalCluster

    spec = _spec(args.tasks, args.steps, args.solver)
    warm_task = replace(spec.tasks[0], settings={**spec.tasks[0].settings, "steps": 20})
    load = os.getloadavg()[0]
    run_task(warm_task)
    start = time.perf_counter()
    cluster = LocalCluster(
        n_workers=args.workers, threads_per_worker=1, processes=True, dashboard_address=":0"
    )
    client = Client(cluster)
    client.wait_for_workers(args.workers)
    startup = time.perf_counter() - start
    runs = []
    try:
        client.run(run_task, warm_task)  # every worker: imports and compiled kernels
        for repeat in range(args.repeat):
            with tempfile.TemporaryDirectory() as folder:
                runs.append(_measure(spec, Path(folder), cluster.scheduler_address, args.workers))
            r = runs[-1]
            print(
                f"run {repeat + 1}: serial {r['serial_wall_s']:.2f} s, {args.workers} workers "
                f"{r['dask_wall_s']:.2f} s, ratio {r['throughput_ratio']:.2f}x, scheduling "
                f"{r['scheduling_overhead_pct']:.2f} %, tail idle {r['tail_idle_pct']:.1f} %, "
                f"task slowdown {r['task_slowdown']:.2f}x, same results {r['same_results']}"
            )
    finally:
        client.close()
        cluster.close()

    best = max(runs, key=lambda r: r["throughput_ratio"])
    figures = {
        "tasks": args.tasks,
        "steps": args.steps,
        "workers": args.workers,
        "solver": args.solver,
        "load_average_before": load,
        "cluster_start_s": startup,
        "mean_task_s_serial": min(r["mean_task_s_serial"] for r in runs),
        "ratio_of_best_walls": min(r["serial_wall_s"] for r in runs)
        / min(r["dask_wall_s"] for r in runs),
        "median_ratio": sorted(r["throughput_ratio"] for r in runs)[len(runs) // 2],
        "max_scheduling_overhead_pct": max(r["scheduling_overhead_pct"] for r in runs),
        "runs": runs,
    }
    same = all(r["same_results"] for r in runs) and not any(r["errors"] for r in runs)
    print(
        f"{args.tasks} tasks x {args.steps} steps ({args.solver}), mean task "
        f"{figures['mean_task_s_serial']:.2f} s serially; load average before {load:.2f}; "
        f"cluster start {startup:.1f} s (not included)"
    )
    print(
        f"throughput ratio      {figures['ratio_of_best_walls']:.2f}x best walls, "
        f"{figures['median_ratio']:.2f}x median of {len(runs)} (target >= 1.8x)"
    )
    print(
        f"scheduling overhead   {figures['max_scheduling_overhead_pct']:.2f} % at most "
        "(target < 5 %)"
    )
    print(
        f"best run: tail idle {best['tail_idle_pct']:.1f} %, all non-task time "
        f"{best['non_task_pct']:.1f} %, task slowdown {best['task_slowdown']:.2f}x"
    )
    print(f"same results          {same}")
    if args.json is not None:
        args.json.write_text(json.dumps(figures, indent=1))
    return 0 if same else 1


if __name__ == "__main__":
    raise SystemExit(main())
