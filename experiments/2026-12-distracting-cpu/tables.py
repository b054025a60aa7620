"""Print NOTES.md's tables from the finished runs: every run's evaluation return by step, per algorithm and task
the mean +- sample std at 10k and 20k agent steps with rliable's IQM of each run's best return / 1000 and its 95%
stratified-bootstrap interval, and the distracted arms side by side (final return and area under the curve). The
undistracted DrQ-v2 and pixel DrQv2-EF runs are the CPU grid's; the latent rerun (drqv2_ef_latent_v2) is in
results/latent-v2.

    python experiments/2026-12-distracting-cpu/tables.py
"""

import os

import numpy as np
import pandas as pd

from sb3_ef.analysis.metrics import load_records, records_to_scores, returns_at, rliable_metrics

HERE = os.path.dirname(os.path.abspath(__file__))
FOLDERS = (os.path.join(HERE, "results"), os.path.join(HERE, "..", "2026-cpu-grid", "results", "cpu"))
TASKS = {"dmc-distracting/cartpole-balance-v0": "distracted", "dmc/cartpole-balance-v0": "undistracted"}
NAMES = {
    "DrQv2": "DrQ-v2",
    "DrQv2EF": "DrQv2-EF pixel",
    "drqv2_ef_latent": "DrQv2-EF latent",
    "drqv2_ef_latent_v2": "DrQv2-EF latent v2",
}
STEPS = tuple(range(2000, 20001, 2000))


def finished_records() -> pd.DataFrame:
    """The finished runs of both folders on the two cartpole-balance tasks."""
    records = pd.concat([load_records(folder, finished_only=True) for folder in FOLDERS], ignore_index=True)
    return records[records["task"].isin(TASKS)].drop_duplicates(["algo", "task", "seed", "step"], keep="last")


def markdown(table: pd.DataFrame) -> str:
    lines = ["| " + " | ".join(table.columns) + " |", "|" + "---|" * len(table.columns)]
    lines += ["| " + " | ".join(str(value) for value in row) + " |" for row in table.itertuples(index=False)]
    return "\n".join(lines)


def per_run(records: pd.DataFrame) -> pd.DataFrame:
    wide = records.pivot_table(index=["task", "algo", "seed"], columns="step", values="return").reindex(columns=STEPS)
    rows = []
    for (task, algo, seed), returns in wide.iterrows():
        cells = ["" if pd.isna(value) else f"{value:.0f}" for value in returns]
        rows.append([f"{NAMES[algo]}, {TASKS[task]}, s{seed}", *cells])
    return pd.DataFrame(rows, columns=["run", *(f"{step // 1000}k" for step in STEPS)])


def summary(records: pd.DataFrame) -> pd.DataFrame:
    at = returns_at(records, (10000, 20000)).set_index(["algo", "task", "step"])
    rows = []
    for task in TASKS:
        scores = records_to_scores(records[records["task"] == task])
        iqm = rliable_metrics(scores).query("metric == 'IQM'").set_index("algo")
        for algo, row in iqm.iterrows():
            cells = [f"{at.loc[(algo, task, step), 'mean']:.0f} +- {at.loc[(algo, task, step), 'std']:.0f}"
                     for step in (10000, 20000)]  # fmt: skip
            seeds = scores[scores["algo"] == algo]["seed"].nunique()
            interval = f"{row['estimate']:.3f} ({row['lower']:.3f}-{row['upper']:.3f})"
            rows.append([f"{NAMES[algo]}, {TASKS[task]}", *cells, interval, seeds])
    columns = ["algorithm", "10k steps (20k frames)", "20k steps (40k frames)", "IQM of best (interval)", "seeds"]
    return pd.DataFrame(rows, columns=columns)


def side_by_side(records: pd.DataFrame, task: str = "dmc-distracting/cartpole-balance-v0") -> pd.DataFrame:
    """Per algorithm on ``task``: mean +- sample std over the seeds of the final (20k) return and of the area under
    the evaluation curve from 2k to 20k steps (trapezoids, divided by the 18k steps: the curve's mean level)."""
    wide = records[records["task"] == task].pivot_table(index=["algo", "seed"], columns="step", values="return")
    wide = wide.reindex(columns=STEPS)
    area = wide.apply(lambda row: np.trapezoid(row.to_numpy(), STEPS) / (STEPS[-1] - STEPS[0]), axis=1)
    rows = []
    for algo in NAMES:
        if algo not in wide.index.get_level_values("algo"):
            continue
        final, auc = wide.loc[algo][STEPS[-1]], area.loc[algo]
        rows.append([NAMES[algo], f"{final.mean():.0f} +- {final.std():.0f}", f"{auc.mean():.0f} +- {auc.std():.0f}",
                     len(final)])  # fmt: skip
    return pd.DataFrame(rows, columns=["arm", "final return (20k steps)", "area under the curve / 18k", "seeds"])


if __name__ == "__main__":
    records = finished_records()
    print(markdown(per_run(records)), end="\n\n")
    print(markdown(summary(records)), end="\n\n")
    print(markdown(side_by_side(records)))
