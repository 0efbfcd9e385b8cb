"""`liverinv tables`: a study's gathered fits (fits.nc) as table.csv and table.md, and the
ranking of its laws (`--ranking-csv`)."""

from __future__ import annotations

import sys
from pathlib import Path


def register(sub):
    p = sub.add_parser("tables", help="tables of a study's gathered fits (CSV and Markdown)", description=__doc__)
    p.add_argument("fits", type=Path, help="gathered fits (liverinv gather)")
    p.add_argument("--csv", type=Path, required=True)
    p.add_argument("--md", type=Path, required=True)
    p.add_argument("--ranking-csv", type=Path, help="the laws ranked by Phi at the common noise levels, with "
                                                    "the paired test against the first (one row when the study "
                                                    "fits one law)")
    p.set_defaults(func=run)


def run(args) -> int:
    from ..fileio import atomic_path
    from ..pipeline.tables import fit_table, markdown_table, ranking, ranking_table
    from ..pipeline.gather import load_dataset

    ds = load_dataset(args.fits)
    rank = ranking(ds)   # the paired tests once, for the CSV and the Markdown
    with atomic_path(args.csv) as tmp:
        fit_table(ds).to_csv(tmp, index=False)
    if args.ranking_csv:
        with atomic_path(args.ranking_csv) as tmp:
            ranking_table(ds, rank).to_csv(tmp, index=False)
    md = markdown_table(ds, rank)
    with atomic_path(args.md) as tmp:
        tmp.write_text(md)
    print(md)
    bad = ds.status.values[ds.status.values != "ok"]
    if bad.size:
        print(f"warning: {bad.size} of {ds.status.size} fits are flagged or failed; see {args.md}", file=sys.stderr)
    return 0
