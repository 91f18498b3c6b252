"""``inhand-analyze PATH... [--table comparison|robustness|cube] [--format markdown|csv]
[--jobs N]``

Reads every run log (``*.mcap``) below the paths, prints the paper's tables with the mean and
standard deviation over seeds beside the paper's own figures, and writes into ``--out``
(default: ``analysis/`` inside the first path): the tidy frames (``runs``, ``iterations``,
``episodes``) as CSV and Parquet, each table as CSV, and PNG plots (learning curves with seed
bands; success and drops by goal group and by perturbation). Corrupt or foreign files are
skipped with a warning naming them. Large sets of logs are read by ``--jobs`` processes at
once (default: one per core).
"""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

from inhand_exp.analysis import plots, tables
from inhand_exp.analysis.frames import load


def _write(frame, out: Path, name: str) -> None:
    frame.to_csv(out / f"{name}.csv", index=False)
    frame.to_parquet(out / f"{name}.parquet", index=False)


def _positive(text: str) -> int:
    try:
        n = int(text)
    except ValueError:
        n = 0
    if n < 1:
        raise argparse.ArgumentTypeError(f"--jobs must be a whole number >= 1, not {text!r}")
    return n


def main(argv: list[str] | None = None) -> None:
    parser = argparse.ArgumentParser(prog="inhand-analyze", description=__doc__,
                                     formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("paths", nargs="+", help="run logs or directories holding them")
    parser.add_argument("--table", choices=tables.TABLES, action="append",
                        help="table(s) to print (default: every table with episodes)")
    parser.add_argument("--format", choices=("markdown", "csv"), default="markdown")
    parser.add_argument("--out", type=Path, default=None, help="output directory")
    parser.add_argument("--jobs", type=_positive, default=None,
                        help="processes reading the logs (default: one per core)")
    args = parser.parse_args(argv)
    try:
        frames = load(args.paths, warn=lambda m: print(m, file=sys.stderr), jobs=args.jobs)
    except FileNotFoundError as err:
        print(f"inhand-analyze: {err}", file=sys.stderr)
        raise SystemExit(2) from None
    if frames.runs.empty:
        print(f"inhand-analyze: no run logs below {' '.join(args.paths)}", file=sys.stderr)
        raise SystemExit(2)
    first = Path(args.paths[0])
    out = args.out or (first if first.is_dir() else first.parent) / "analysis"
    out.mkdir(parents=True, exist_ok=True)
    for name in ("runs", "iterations", "episodes"):
        _write(getattr(frames, name), out, name)
    print(f"{len(frames.runs)} runs, {len(frames.iterations)} iterations, "
          f"{len(frames.episodes)} episodes; {len(frames.skipped)} files skipped")
    for name in args.table or tables.TABLES:
        rows = tables.build(frames.episodes, name)
        if rows.empty and not args.table:
            continue
        print(f"\n{name}\n" + tables.render(rows, name, args.format))
        if not rows.empty:
            rows.to_csv(out / f"table_{name}.csv", index=False)
    made = [plots.learning_curves(frames.iterations, out / "learning_curves.png"),
            plots.outcome_bars(frames.episodes, "group", out / "by_group.png")]
    if not frames.episodes.empty and frames.episodes["perturb"].nunique() > 1:
        made.append(plots.outcome_bars(frames.episodes, "perturb", out / "by_perturbation.png",
                                       hue=("learner", "noise")))
    print(f"\nwritten to {out}: frames (CSV, Parquet), tables, "
          f"{sum(p is not None for p in made)} plots")
