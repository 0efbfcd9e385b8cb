"""Where a workflow's time went: the Snakemake benchmark files of a results folder, summed per
rule (and per study for the study rules), with each rule's share of the job time.

    python benchmarks/study_times.py results [--study paper-table3]

Job time is each job's own wall time (`s` of its benchmark file); with `--cores 2` two jobs run
at once, so the sum over rules is up to twice the workflow's wall time. CPU time over job time
shows how much of a job ran on more than one core (or waited for one).
"""

from __future__ import annotations

import argparse
from pathlib import Path

import pandas as pd


def job_times(results: Path) -> pd.DataFrame:
    """One row per benchmark file under `results`/benchmarks: study ('data' for the shared data
    rules), rule, job (the file's stem), wall s, cpu s, max RSS MB."""
    rows = []
    for path in sorted((results / "benchmarks").rglob("*.tsv")):
        bench = pd.read_csv(path, sep="\t")
        if bench.empty:
            continue
        study = path.parent.name if path.parent.name != "benchmarks" else "data"
        rows.append({"study": study, "rule": path.stem.split("_")[0], "job": path.stem,
                     "wall_s": float(bench["s"].iloc[-1]), "cpu_s": float(bench["cpu_time"].iloc[-1]),
                     "max_rss_MB": float(bench["max_rss"].iloc[-1])})
    if not rows:
        raise SystemExit(f"no benchmark files under {results / 'benchmarks'}")
    return pd.DataFrame(rows)


def per_rule(jobs: pd.DataFrame) -> pd.DataFrame:
    """Jobs, summed and longest wall time, CPU time and share of all job time per study and rule."""
    table = jobs.groupby(["study", "rule"]).agg(jobs=("job", "size"), wall_s=("wall_s", "sum"),
                                                longest_s=("wall_s", "max"), cpu_s=("cpu_s", "sum"))
    table["share_%"] = 100.0 * table["wall_s"] / table["wall_s"].sum()
    return table.sort_values("wall_s", ascending=False).round(1)


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("results", type=Path, help="the workflow's results folder")
    ap.add_argument("--study", help="only this study's rules (and the shared data rules)")
    ap.add_argument("--jobs", action="store_true", help="also list every job")
    args = ap.parse_args(argv)
    jobs = job_times(args.results)
    if args.study:
        jobs = jobs[jobs["study"].isin([args.study, "data"])]
    with pd.option_context("display.width", 200, "display.max_rows", 500):
        print(per_rule(jobs).to_string())
        print(f"\nall jobs: {jobs['wall_s'].sum():.0f} s of job time, {jobs['cpu_s'].sum():.0f} s CPU")
        if args.jobs:
            print()
            print(jobs.sort_values("wall_s", ascending=False).round(1).to_string(index=False))


if __name__ == "__main__":
    main()
