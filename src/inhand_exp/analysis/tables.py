"""The paper's tables from the episode frame: rates per seed, then mean and spread over seeds,
beside the paper's published figures (``paper_results.csv``)."""

from __future__ import annotations

import importlib.resources
import io

import numpy as np
import pandas as pd

TABLES = ("comparison", "robustness", "cube")
METRICS = ("success_rate", "drop_rate", "timeout_rate", "avg_time_s", "flipped_rate")
NEEDS_FLIP = "hard, needs flip"
NO_FLIP = "hard, no flip needed"
LONE_DOWN = "medium, lone down"
PAPER_ORDER = {"group": ("easy", "medium", LONE_DOWN, "hard", NEEDS_FLIP, NO_FLIP),
               "perturb": ("none", "heavier", "lighter", "thicker", "thinner", "longer",
                           "shorter"),
               "noise": ("none", "paper")}


def paper_results() -> pd.DataFrame:
    text = importlib.resources.files("inhand_exp").joinpath("paper_results.csv").read_text()
    return pd.read_csv(io.StringIO(text))


def per_seed(episodes: pd.DataFrame, keys: list[str]) -> pd.DataFrame:
    """Success, drop and timeout rates, the mean time of the successes and the share of
    episodes that made a flip (of those that counted their flips; NaN where none did), per
    ``keys`` + seed."""
    def rates(g: pd.DataFrame) -> pd.Series:
        wins = g[g["success"]]
        flips = g["n_flips"].dropna() if "n_flips" in g else pd.Series(dtype=float)
        return pd.Series({"episodes": len(g), "success_rate": g["success"].mean(),
                          "drop_rate": g["dropped"].mean(), "timeout_rate": g["timeout"].mean(),
                          "avg_time_s": wins["sim_time_s"].mean() if len(wins) else np.nan,
                          "flipped_rate": (flips > 0).mean() if len(flips) else np.nan})

    return episodes.groupby([*keys, "seed"], dropna=False).apply(
        rates, include_groups=False).reset_index()


def over_seeds(seeds: pd.DataFrame, keys: list[str]) -> pd.DataFrame:
    """Mean and standard deviation (over seeds, ddof 1; NaN for one seed) of every metric."""
    agg = {f"{m}_{s}": (m, s) for m in METRICS for s in ("mean", "std")}
    out = seeds.groupby(keys, dropna=False).agg(seeds=("seed", "nunique"),
                                                episodes=("episodes", "sum"), **agg)
    return out.reset_index()


def _flagged(episodes: pd.DataFrame, group: str, flag: str) -> pd.DataFrame:
    """The episodes of ``group`` whose goal pair carries ``flag`` (False where a log lacks it)."""
    marked = episodes[flag].eq(True) if flag in episodes else False
    return episodes[(episodes["group"] == group) & marked]


def _unflagged(episodes: pd.DataFrame, group: str, flag: str) -> pd.DataFrame:
    """The other episodes of ``group``; none where no episode of it carries ``flag`` (the row
    would repeat the whole group's)."""
    flagged = _flagged(episodes, group, flag)
    if flagged.empty:
        return flagged
    return episodes[(episodes["group"] == group) & ~episodes.index.isin(flagged.index)]


def _with_subset_rows(episodes: pd.DataFrame) -> pd.DataFrame:
    """The episodes, plus again as rows of their own: the hard pairs that need a flip and
    the other hard pairs, and the medium pairs whose lone finger must end lower on the pole
    (goals.lone_descends)."""
    return pd.concat([episodes,
                      _flagged(episodes, "medium", "lone_down").assign(group=LONE_DOWN),
                      _flagged(episodes, "hard", "needs_flip").assign(group=NEEDS_FLIP),
                      _unflagged(episodes, "hard", "needs_flip").assign(group=NO_FLIP)],
                     ignore_index=True)


def build(episodes: pd.DataFrame, table: str) -> pd.DataFrame:
    """The rows of ``table`` (comparison, robustness, cube) with the paper's figures beside."""
    if table not in TABLES:
        raise ValueError(f"table must be one of {TABLES}, got {table!r}")
    if episodes.empty:
        return pd.DataFrame()
    paper = paper_results()
    if table == "comparison":
        eps = _with_subset_rows(episodes[(episodes["object"] == "pole")
                                         & (episodes["perturb"] == "none")
                                         & (episodes["noise"] == "none")])
        keys = ["learner", "variant", "group"]
        ref = paper[paper["study"] == "comparison"].rename(columns={"method": "learner"})
    elif table == "robustness":
        eps = episodes[(episodes["object"] == "pole") & (episodes["group"] == "medium")]
        keys = ["learner", "variant", "perturb", "noise"]
        ref = paper[paper["study"] == "robustness"].rename(columns={"method": "learner"})
    else:
        eps = episodes[episodes["object"] == "cube"]
        keys = ["learner", "variant", "object"]
        ref = paper[paper["study"] == "cube"].rename(columns={"method": "learner"})
    if eps.empty:
        return pd.DataFrame()
    out = over_seeds(per_seed(eps, keys), keys)
    out = in_paper_order(out, [k for k in keys if k in out])
    ref = ref[[*(k for k in keys if k != "variant"), "success_rate", "drop_rate",
               "avg_time_s"]].rename(
        columns={"success_rate": "paper_success", "drop_rate": "paper_drop",
                 "avg_time_s": "paper_time_s"})
    out = out.merge(ref, on=[k for k in keys if k != "variant"], how="left")
    if table == "robustness":
        out = _vs_trained(out, eps)
    return out


SAME = ["learner", "variant", "noise"]  # what a Table III row is compared within


def _vs_trained(rows: pd.DataFrame, episodes: pd.DataFrame) -> pd.DataFrame:
    """Each row's change from the trained object (``perturb=none``) of the same learner,
    variant and noise, on the test pairs both evaluated (``paired``): the mean of the perturbed
    success minus the trained object's over those pairs, pooled over the seeds both ran (so a
    cell that a sweep has not run for every seed yet is compared with the same seeds of the
    trained object), its standard error, and the number of pairs; and the paper's change. A
    pair the perturbed object was given again (another X0 or Xg: the thicker, thinner, longer
    and shorter poles draw again the pairs they cannot hold) is left out, so the change is not
    that of an easier or harder set. NaN where the trained object was not evaluated."""
    keys = [*SAME, "perturb"]
    stats = paired(episodes)
    rows = rows.copy()
    idx = pd.MultiIndex.from_frame(rows[keys])
    for col in ("change", "se", "pairs"):
        name = "vs_trained" if col == "change" else f"vs_trained_{col}"
        rows[name] = stats[col].reindex(idx).to_numpy(float) if len(stats) else np.nan
    ref = rows[rows["perturb"] == "none"].set_index(SAME)["paper_success"]
    rows["paper_vs_trained"] = rows["paper_success"].to_numpy(dtype=float) - ref.reindex(
        pd.MultiIndex.from_frame(rows[SAME])).to_numpy(dtype=float)
    return rows


def paired(episodes: pd.DataFrame) -> pd.DataFrame:
    """Each perturbed setting against the trained object on the test pairs both evaluated (the
    same seed, episode, X0 and Xg; a pair the perturbed object was given again is left out):
    ``change``, the mean success difference; ``se``, its standard error,
    ``sqrt(b + c - (c - b)^2 / n) / n`` with ``b`` the pairs only the trained object solved and
    ``c`` those only the perturbed one did (a change smaller than about twice this is within
    what the same policy gives run to run); ``pairs``, ``n``. Indexed by learner, variant, noise
    and perturb."""
    names = [*SAME, "perturb"]
    empty = pd.DataFrame(columns=["change", "se", "pairs"], dtype=float)
    if episodes.empty:
        return empty
    eps = episodes.assign(pair=episodes["x0"].astype(str) + episodes["xg"].astype(str))
    match = [*SAME, "seed", "episode", "pair"]
    base = eps[eps["perturb"] == "none"][[*match, "success"]]
    both = eps.merge(base, on=match, suffixes=("", "_trained"))
    out = {}
    for key, g in both.groupby(names, dropna=False):
        n = len(g)
        b = int((g["success_trained"] & ~g["success"]).sum())
        c = int((g["success"] & ~g["success_trained"]).sum())
        out[key] = {"change": (c - b) / n, "pairs": n,
                    "se": np.sqrt(max(b + c - (c - b) ** 2 / n, 0.0)) / n}
    if not out:
        return empty
    return pd.DataFrame.from_dict(out, orient="index").rename_axis(names)


def paper_rank(column: pd.Series) -> pd.Series:
    """Sort keys putting goal groups, perturbations and noise in the paper's order (each
    flagged subset after its group); other columns sort as they are."""
    order = PAPER_ORDER.get(column.name)
    if order is None:
        return column
    return column.map({v: i for i, v in enumerate(order)}).fillna(len(order))


def in_paper_order(frame: pd.DataFrame, keys: list[str]) -> pd.DataFrame:
    return frame.sort_values(keys, key=paper_rank, kind="stable").reset_index(drop=True)


def _cell(mean: float, std: float, pct: bool) -> str:
    if pd.isna(mean):
        return "-"
    scale, unit, digits = (100, " %", 1) if pct else (1, "", 2)
    text = f"{mean * scale:.{digits}f}"
    if not pd.isna(std):
        text += f" ± {std * scale:.{digits}f}"
    return text + unit


def _ref(v: float, pct: bool) -> str:
    return "-" if pd.isna(v) else (f"{v * 100:.1f} %" if pct else f"{v:.2f}")


def _points(v: float, se: float = np.nan) -> str:
    if pd.isna(v):
        return "-"
    return f"{v * 100:+.1f} pts" if pd.isna(se) else f"{v * 100:+.1f} ± {se * 100:.1f} pts"


def _count(v: float) -> str:
    return "-" if pd.isna(v) else str(int(v))


def render(rows: pd.DataFrame, table: str, fmt: str = "markdown") -> str:
    """``rows`` (from ``build``) as a markdown table, or CSV."""
    if rows.empty:
        return f"(no episodes for the {table} table)"
    if fmt == "csv":
        return rows.to_csv(index=False)
    if fmt != "markdown":
        raise ValueError(f"format must be markdown or csv, got {fmt!r}")
    keys = [c for c in ("learner", "variant", "group", "perturb", "noise", "object")
            if c in rows.columns and (c != "variant" or rows[c].nunique() > 1)]
    vs = "vs_trained" in rows.columns  # Table III: the change from the trained object
    flips = rows.get("flipped_rate_mean", pd.Series(dtype=float)).notna().any()
    head = [*keys, "seeds", "episodes", "success", "paper",
            *(("vs trained object", "pairs", "paper") if vs else ()), "drops", "paper", "timeouts",
            "avg time (s)", "paper", *(("flipped",) if flips else ())]
    lines = ["| " + " | ".join(head) + " |", "|" + "---|" * len(head)]
    for _, r in rows.iterrows():
        cells = [str(r[k]) for k in keys] + [
            str(int(r["seeds"])), str(int(r["episodes"])),
            _cell(r["success_rate_mean"], r["success_rate_std"], True),
            _ref(r.get("paper_success"), True),
            *((_points(r["vs_trained"], r.get("vs_trained_se", np.nan)),
               _count(r.get("vs_trained_pairs", np.nan)),
               _points(r["paper_vs_trained"])) if vs else ()),
            _cell(r["drop_rate_mean"], r["drop_rate_std"], True), _ref(r.get("paper_drop"), True),
            _cell(r["timeout_rate_mean"], r["timeout_rate_std"], True),
            _cell(r["avg_time_s_mean"], r["avg_time_s_std"], False),
            _ref(r.get("paper_time_s"), False),
            *((_cell(r["flipped_rate_mean"], r["flipped_rate_std"], True),) if flips else ())]
        lines.append("| " + " | ".join(cells) + " |")
    return "\n".join(lines)
