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


def test_prediction_and_saliency_figures_are_labelled():
    from sb3_ef.analysis.plots import prediction_figure, saliency_figure
    from sb3_ef.analysis.prediction import figure_eight_actions
    from sb3_ef.analysis.report import foresight_report, record_rollout
    from tests.helpers.analysis import DotEnv, FakeModel

    probe = figure_eight_actions(4, 2, period=4)
    report = foresight_report(FakeModel(), record_rollout(DotEnv(), lambda _obs, step: probe[step], 4, seed=0))
    figure = prediction_figure(report, "fake on dots")
    [axis] = figure.axes
    [context] = axis.child_axes  # labels the context row, above the grid
    assert [label.get_text() for label in axis.get_yticklabels()] == ["context", "predicted", "true"]
    assert [label.get_text() for label in axis.get_xticklabels()] == ["t+1", "t+2", "t+3", "t+4"]
    contexts = report.rollout.first_observation.shape[0] // 3
    expected = [*(f"t-{lag}" for lag in range(contexts - 1, 0, -1)), "t"]
    assert [label.get_text() for label in context.get_xticklabels()] == expected
    assert axis.get_title() == "fake on dots"
    titles = [axis.get_title() for axis in saliency_figure(report, "fake").axes]
    assert titles == ["predicted frame", "h_a saliency (red)", "h_s saliency (blue)", "true agent mask"]
