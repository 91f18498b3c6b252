"""PNG plots from the frames: learning curves with seed bands, success and drops by goal group
and by perturbation."""

from __future__ import annotations

import warnings
from pathlib import Path

import matplotlib

matplotlib.use("Agg")  # files only, no display
import matplotlib.pyplot as plt  # noqa: E402
import numpy as np  # noqa: E402
import pandas as pd  # noqa: E402

from inhand_exp.analysis.tables import paper_rank, per_seed  # noqa: E402


def learning_curves(iterations: pd.DataFrame, path: Path, smooth: int = 8) -> Path | None:
    """Batch success against frames, one line per setting (mean over seeds, band: +-1 std)."""
    if iterations.empty or "success_rate" not in iterations:
        return None
    fig, ax = plt.subplots(figsize=(7, 4))
    for setting, runs in iterations.groupby(["learner", "variant", "object", "perturb",
                                             "noise"], dropna=False):
        grid = np.linspace(0, runs["frames"].max(), 100)
        curves = []
        for _, seed in runs.groupby("seed"):
            seed = seed.sort_values("frames").drop_duplicates("frames", keep="last")
            ys = seed["success_rate"].rolling(smooth, min_periods=1).mean()
            curves.append(np.interp(grid, seed["frames"], ys, left=np.nan, right=np.nan))
        c = np.array(curves)
        with warnings.catch_warnings():  # frames no seed reached: NaN, not plotted
            warnings.simplefilter("ignore", RuntimeWarning)
            mean, std = np.nanmean(c, 0), np.nanstd(c, 0)
        label = " ".join(str(v) for v in setting if v not in ("none", "default", None)) + \
            f" ({len(curves)} seed{'s' if len(curves) > 1 else ''})"
        ax.plot(grid, mean, label=label)
        ax.fill_between(grid, mean - std, mean + std, alpha=0.2)
    ax.set_xlabel("frames (mid-level actions or control steps)")
    ax.set_ylabel(f"batch success (rolling {smooth} iterations)")
    ax.set_ylim(0, 1)
    ax.legend(fontsize=8)
    fig.tight_layout()
    fig.savefig(path, dpi=120)
    plt.close(fig)
    return path


def outcome_stats(episodes: pd.DataFrame, by: str, hue: tuple[str, ...] = ("learner",)
                  ) -> pd.DataFrame:
    """Success and drop rate, mean and std over seeds, per setting of ``hue`` and ``by``."""
    keys = [*hue, by]
    return per_seed(episodes, keys).groupby(keys, dropna=False).agg(
        success=("success_rate", "mean"), success_std=("success_rate", "std"),
        drop=("drop_rate", "mean"), drop_std=("drop_rate", "std")).reset_index()


def outcome_bars(episodes: pd.DataFrame, by: str, path: Path,
                 hue: tuple[str, ...] = ("learner",)) -> Path | None:
    """Success and drop rate (mean over seeds, error bar: std) per ``by`` value, one bar per
    setting of the ``hue`` columns (the learner; for Table III also the noise)."""
    if episodes.empty or by not in episodes:
        return None
    stats = outcome_stats(episodes, by, hue)
    cats = list(dict.fromkeys(stats.sort_values(by, key=paper_rank, kind="stable")[by]))
    settings = list(dict.fromkeys(zip(*(stats[h] for h in hue), strict=True)))
    fig, axes = plt.subplots(1, 2, figsize=(9, 3.5), sharey=True)
    width = 0.8 / max(len(settings), 1)
    for ax, metric in zip(axes, ("success", "drop"), strict=True):
        for j, setting in enumerate(settings):
            mine = np.logical_and.reduce([stats[h] == v for h, v in zip(hue, setting,
                                                                          strict=True)])
            s = stats[mine].set_index(by).reindex(cats)
            label = ", ".join(f"{h} {v}" if h != "learner" else str(v)
                              for h, v in zip(hue, setting, strict=True))
            ax.bar(np.arange(len(cats)) + j * width, s[metric], width,
                   yerr=s[f"{metric}_std"].fillna(0), label=label, capsize=2)
        ax.set_xticks(np.arange(len(cats)) + width * (len(settings) - 1) / 2, cats)
        ax.set_title(f"{metric} rate by {by}")
        ax.set_ylim(0, 1)
    axes[0].legend(fontsize=8)
    fig.tight_layout()
    fig.savefig(path, dpi=120)
    plt.close(fig)
    return path
