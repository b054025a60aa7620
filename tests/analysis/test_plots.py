import pandas as pd
from PIL import Image
from test_metrics import hand_example

from sb3_ef.analysis.metrics import efficiency_normalized_score, rliable_metrics
from sb3_ef.analysis.plots import plot_ens, plot_intervals, plot_learning_curves


def test_plots_are_written_as_images(tmp_path):
    scores = hand_example()
    paths = plot_learning_curves(scores.assign(task=scores.task.map({"t1": "dmc/t1", "t2": "t2"})), tmp_path)
    assert sorted(path.rsplit("/", 1)[1] for path in paths) == ["curve_dmc_t1.png", "curve_t2.png"]
    ens_path = plot_ens(efficiency_normalized_score(scores), tmp_path / "ens.png")
    table = rliable_metrics(scores[scores.seed == 0].assign(score=lambda df: df.score / 200), reps=20)
    interval_path = plot_intervals(table, tmp_path / "rliable.png")
    for path in [*paths, ens_path, interval_path]:
        width, height = Image.open(path).size
        assert width > 100 and height > 100
    assert isinstance(table, pd.DataFrame)
