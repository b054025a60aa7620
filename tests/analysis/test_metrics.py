import numpy as np
import pandas as pd
import pytest

from sb3_ef.analysis.metrics import (
    best_scores,
    efficiency_normalized_score,
    ens_table,
    load_records,
    records_to_scores,
    returns_at,
    rliable_metrics,
)
from sb3_ef.analysis.records import RECORD_COLUMNS


def hand_example() -> pd.DataFrame:
    rows = [
        # task t1, both algos evaluated at steps 0, 10, 20 with two seeds
        ("A", "t1", 0, 0, 0), ("A", "t1", 0, 10, 40), ("A", "t1", 0, 20, 100),
        ("A", "t1", 1, 0, 0), ("A", "t1", 1, 10, 60), ("A", "t1", 1, 20, 100),
        ("B", "t1", 0, 0, 0), ("B", "t1", 0, 10, 80), ("B", "t1", 0, 20, 90),
        ("B", "t1", 1, 0, 0), ("B", "t1", 1, 10, 92), ("B", "t1", 1, 20, 90),
        # task t2, A evaluated only at 0 and 20, B at 0, 10, 20
        ("A", "t2", 0, 0, 0), ("A", "t2", 0, 20, 200),
        ("B", "t2", 0, 0, 0), ("B", "t2", 0, 10, 190), ("B", "t2", 0, 20, 150),
    ]  # fmt: skip
    return pd.DataFrame(rows, columns=["algo", "task", "seed", "step", "score"])


def test_ens_worked_by_hand():
    # t1 curves (mean over seeds): A = 0, 50, 100; B = 0, 86, 90; M = 100.
    #   q=0.95 -> 95 first reached at step 20 (A: 100): A 100/100 = 1.0, B 90/100 = 0.9
    #   q=0.90 -> 90 first reached at step 20:           A 1.0, B 0.9
    #   q=0.85 -> 85 first reached at step 10 (B: 86):   A 50/100 = 0.5, B 0.86
    # t2 curves: A = 0 @0, 200 @20 (interpolated 100 @10); B = 0, 190, 150; M = 200.
    #   q=0.95 -> 190 first reached at step 10 (B): A 100/200 = 0.5, B 190/200 = 0.95; same for 0.90 and 0.85
    # ENS(A) = (1 + 1 + 0.5 + 0.5 + 0.5 + 0.5) / 6 = 4 / 6
    # ENS(B) = (0.9 + 0.9 + 0.86 + 0.95 * 3) / 6 = 5.51 / 6
    ens = efficiency_normalized_score(hand_example())
    assert ens["A"] == pytest.approx(4 / 6)
    assert ens["B"] == pytest.approx(5.51 / 6)
    table = ens_table(hand_example())
    steps = table.drop_duplicates(["task", "threshold"]).set_index(["task", "threshold"])["step"]
    assert steps[("t1", 0.95)] == 20 and steps[("t1", 0.85)] == 10 and steps[("t2", 0.95)] == 10


def test_ens_refuses_missing_algorithms_and_non_positive_maxima():
    scores = hand_example()
    with pytest.raises(ValueError, match="Task 't2' has results for \\['A'\\]"):
        efficiency_normalized_score(scores[~((scores.task == "t2") & (scores.algo == "B"))])
    negative = scores.assign(score=-scores.score - 1)
    with pytest.raises(ValueError, match="positive maximum"):
        efficiency_normalized_score(negative)
    with pytest.raises(ValueError, match="missing \\['score'\\]"):
        efficiency_normalized_score(scores.drop(columns="score"))


def test_records_become_scores_per_task(tmp_path):
    records = pd.DataFrame(
        [
            ("DrQv2EF", "dmc/reacher-easy", 0, 10, 20, 500.0, np.nan),
            ("DrQv2EF", "metaworld/hammer", 0, 10, 20, 1234.0, 0.3),
        ],
        columns=RECORD_COLUMNS,
    )
    (tmp_path / "a").mkdir()
    records.to_csv(tmp_path / "a" / "run.csv", index=False)
    (tmp_path / "other.csv").write_text("x,y\n1,2\n")
    loaded = load_records(tmp_path)
    scores = records_to_scores(loaded)
    assert scores.set_index("task")["score"].to_dict() == {"dmc/reacher-easy": 0.5, "metaworld/hammer": 0.3}
    with pytest.raises(FileNotFoundError, match="No evaluation CSV"):
        load_records(tmp_path / "a" / "missing")


def test_rliable_on_best_scores():
    scores = hand_example()
    scores = scores[scores.seed == 0]
    matrices = best_scores(scores)
    # best per run: A t1 100, A t2 200; B t1 90, B t2 190
    assert matrices["A"].tolist() == [[100.0, 200.0]] and matrices["B"].tolist() == [[90.0, 190.0]]
    table = rliable_metrics(scores.assign(score=scores.score / 200), reps=50).set_index(["algo", "metric"])
    assert table.loc[("A", "Mean"), "estimate"] == pytest.approx(0.75)
    assert table.loc[("B", "Optimality Gap"), "estimate"] == pytest.approx(1 - (0.45 + 0.95) / 2)
    assert (table["lower"] <= table["estimate"] + 1e-9).all() and (table["estimate"] <= table["upper"] + 1e-9).all()
    with pytest.raises(ValueError, match="same number of seeds"):
        best_scores(hand_example()[lambda df: ~((df.task == "t2") & (df.seed == 1)) | (df.algo == "B")])


def test_returns_at_steps_over_seeds():
    rows = [
        ("DrQv2", "dmc/cartpole-balance-v0", 0, 10, 20, 300.0, np.nan),
        ("DrQv2", "dmc/cartpole-balance-v0", 1, 10, 20, 500.0, np.nan),
        ("DrQv2", "dmc/cartpole-balance-v0", 0, 20, 40, 800.0, np.nan),  # seed 1 unfinished
        ("DrQv2", "dmc/cartpole-balance-v0", 1, 15, 30, 900.0, np.nan),  # not a chosen step
    ]
    table = returns_at(pd.DataFrame(rows, columns=RECORD_COLUMNS), (10, 20, 30)).set_index("step")
    assert list(table.index) == [10, 20]
    assert table.loc[10, "mean"] == 400.0 and table.loc[10, "std"] == pytest.approx(np.sqrt(2) * 100)
    assert table.loc[10, "seeds"] == 2 and table.loc[10, "returns"] == [300.0, 500.0]
    assert table.loc[20, "seeds"] == 1 and np.isnan(table.loc[20, "std"])
    with pytest.raises(ValueError, match="non-negative steps, got \\(\\)"):
        returns_at(pd.DataFrame(rows, columns=RECORD_COLUMNS), ())
