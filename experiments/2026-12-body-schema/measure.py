"""The body-schema measurements: does offline EF treat a held tool, a door or a distractor as part of the agent?

Scripted Meta-World episodes (``scripted.py`` beside this file) train an offline EF (``sb3_ef.offline.pretrain``)
per experiment and seed, scored per image region by ``body_schema.py``:

- ``held-tool``: one model on hammer-held and hammer-table episodes; the hammer's error ratio and h_a saliency
  share, held vs on the table;
- ``door``: door-handle episodes (gripper on the handle); the door's;
- ``distractor``: hammer-distractor episodes (the hammer walks on the table by itself); the hammer's against the
  robot's.

``run`` writes ``results.json`` (every score per seed), ``table.md`` (mean and spread over seeds) and one figure per
condition and seed under ``figures/`` (rows: context, prediction, prediction with h_a saliency in yellow, truth with
the robot's mask in blue and the object's in green), and for the held tool ``figure8_s<seed>.png``: the open-loop
prediction of a hand-made figure-eight trajectory from a context with the hammer in the hand (rows: context, then
the predicted frames in three rows). ``table`` prints one table over the ``results.json`` of several folders.

    MUJOCO_GL=egl OMP_NUM_THREADS=1 python experiments/2026-12-body-schema/measure.py run --seeds 0 1 2 --out DIR
    python experiments/2026-12-body-schema/measure.py table DIR [DIR ...]

``--target latent`` trains latent EF instead (``ef_kwargs=dict(target="latent")``): its errors and saliency are
those of the probe decoder that ``pretrain`` trains beside it on detached features (docs/ef.md), so they say what
the features hold, not what a decoder trained end to end would draw.
"""

from __future__ import annotations

import argparse
import json
import os
import time

import numpy as np
import torch as th
from body_schema import cut_region_windows, evaluate_regions, window_figure  # this folder is on sys.path
from scripted import ScriptedCollector, ScriptedEpisode, figure_eight_probe

from sb3_ef.analysis.prediction import frame_grid, save_image
from sb3_ef.offline.episodes import make_episode
from sb3_ef.offline.model import load_pretrained
from sb3_ef.offline.predict import predict_frames
from sb3_ef.offline.pretrain import MODEL, pretrain

#: Experiment -> the scenarios its model trains on, each with the window rule of its evaluation
#: (``require_attached`` of ``cut_region_windows``: the hammer must stay in the hand through a held window; the
#: door's windows all start with the gripper at or near the handle, where babbling began).
EXPERIMENTS: dict[str, dict[str, str | None]] = {
    "held-tool": {"hammer-held": "window", "hammer-table": None},
    "door": {"door-handle": None},
    "distractor": {"hammer-distractor": None},
}


def collect_scenario(
    scenario: str, seed: int, train: int, held_out: int, steps: int, size: int, with_train: bool = True
) -> tuple[list[ScriptedEpisode], list[ScriptedEpisode]]:
    """``train`` episodes without masks (none when not ``with_train``) and ``held_out`` episodes with masks, whose
    indices follow the training ones."""
    with ScriptedCollector(scenario, size=size) as collector:
        indices = range(train) if with_train else range(0)
        train_episodes = [collector.episode(seed, index, steps, with_masks=False) for index in indices]
        held_out_episodes = [collector.episode(seed, index, steps) for index in range(train, train + held_out)]
    return train_episodes, held_out_episodes


def run_experiment(experiment: str, seed: int, args: argparse.Namespace) -> dict:
    """Collect, train one offline EF, score every condition of ``experiment``, write its figures. A model already
    trained in the run folder (``model.pt``) is scored again without collecting training episodes."""
    conditions = EXPERIMENTS[experiment]
    train_per_condition = max(1, args.train_episodes // len(conditions))
    run_dir = os.path.join(args.out, "runs", f"{experiment}_s{seed}")
    trained = os.path.isfile(os.path.join(run_dir, MODEL))
    start = time.perf_counter()
    data = {
        scenario: collect_scenario(
            scenario, seed, train_per_condition, args.eval_episodes, args.steps, args.size, with_train=not trained
        )
        for scenario in conditions
    }
    collect_seconds = time.perf_counter() - start
    start = time.perf_counter()
    if trained:
        model, _ = load_pretrained(os.path.join(run_dir, MODEL))
    else:
        episodes = [make_episode(e.frames, e.actions, source=f"{e.scenario}/{e.reset_seed}")
                    for train, _ in data.values() for e in train]  # fmt: skip
        model, _ = pretrain(
            episodes,
            run_dir,
            encoder=args.encoder,
            context=args.context,
            horizon=args.horizon,
            agent_dim=args.agent_dim,
            steps=args.updates,
            batch_size=args.batch_size,
            learning_rate=args.lr,
            holdout=0,
            checkpoint_every=max(1, args.updates // 4),
            encoder_kwargs={"features_dim": args.features_dim},
            ef_kwargs={
                "decoder_channels": args.decoder_channels,
                "rollout_hidden_dims": (256, 256),
                "target": args.target,
            },
            seed=seed,
            progress_bar=False,
            tensorboard=False,
        )
    train_seconds = time.perf_counter() - start
    results = {}
    start = time.perf_counter()
    for scenario, rule in conditions.items():
        windows = cut_region_windows(data[scenario][1], args.context, args.horizon, args.stride, rule)
        scores = evaluate_regions(model, windows, saliency_windows=args.saliency_windows, seed=seed)
        attached = np.mean([e.attached.mean() for e in data[scenario][1]])
        results[scenario] = {**scores, "attached_fraction": float(attached)}
        figure = np.kron(window_figure(model, windows, 0), np.ones((2, 2, 1), np.uint8))
        save_image(os.path.join(args.out, "figures", f"{scenario}_s{seed}.png"), figure)
        print(experiment, seed, scenario, _headline(scores), flush=True)
    if "hammer-held" in data:  # the paper's unseen-trajectory probe, from a context with the hammer in the hand
        episode = data["hammer-held"][1][0]
        context = episode.frames[: args.context]
        predicted = predict_frames(model, context, figure_eight_probe(args.figure_eight_steps))
        path = os.path.join(args.out, "figures", f"figure8_s{seed}.png")
        grid = frame_grid([context.transpose(0, 2, 3, 1), *np.array_split(predicted, 3)])
        save_image(path, np.kron(grid, np.ones((2, 2, 1), np.uint8)))
    timing = {"collect_seconds": collect_seconds, "evaluate_seconds": time.perf_counter() - start}
    if not trained:
        timing["train_seconds"] = train_seconds
    return {"experiment": experiment, "seed": seed, **timing, "conditions": results}


def _headline(scores: dict) -> str:
    parts = []
    for region, values in scores.items():
        if "ratio" in values:
            parts.append(f"{region}: ratio {values['ratio']:.3f}")
        if "saliency_enrichment" in values:
            parts.append(f"{region}: share {values['saliency_share']:.3f} x{values['saliency_enrichment']:.2f}")
    return "; ".join(parts)


#: Table columns: (header, region, key).
TABLE_COLUMNS = (
    ("object ratio", "object", "ratio"),
    ("object MSE, EF", "object", "model_mse"),
    ("object MSE, copy", "object", "copy_mse"),
    ("robot ratio", "agent", "ratio"),
    ("frame ratio", "frame", "ratio"),
    ("object h_a share", "object", "saliency_share"),
    ("object area", "object", "saliency_fraction"),
    ("object enrichment", "object", "saliency_enrichment"),
    ("robot enrichment", "agent", "saliency_enrichment"),
    ("near-robot enrichment", "near_agent", "saliency_enrichment"),
    ("rest enrichment", "rest", "saliency_enrichment"),
    ("object moved t→t+H (m)", "windows", "object_motion"),
    ("windows moving > 1 cm", "windows", "moving_fraction"),
)


def summary_table(runs: list[dict]) -> str:
    """Markdown: one row per condition, mean +- sample std over seeds (each seed's value in the last column)."""
    lines = [
        "| experiment | condition | seeds | windows | " + " | ".join(h for h, _, _ in TABLE_COLUMNS) + " |",
        "|" + "---|" * (4 + len(TABLE_COLUMNS)),
    ]
    grouped: dict[tuple[str, str], list[dict]] = {}
    for run in runs:
        for scenario, scores in run["conditions"].items():
            grouped.setdefault((run["experiment"], scenario), []).append(scores)
    for (experiment, scenario), seeds in grouped.items():
        cells = []
        for _, region, key in TABLE_COLUMNS:
            values = np.array([_region_value(scores, region, key) for scores in seeds], dtype=float)
            spread = f" ± {np.std(values, ddof=1):.3f}" if len(values) > 1 else ""
            cells.append(f"{np.mean(values):.3f}{spread}")
        windows = "/".join(str(scores["windows"]["count"]) for scores in seeds)
        lines.append(f"| {experiment} | {scenario} | {len(seeds)} | {windows} | " + " | ".join(cells) + " |")
    return "\n".join(lines) + "\n"


#: Keys of a condition's scores that are not the object's region.
NOT_OBJECTS = ("agent", "frame", "near_agent", "rest", "windows", "attached_fraction")


def _region_value(scores: dict, region: str, key: str) -> float:
    if region == "object":
        region = next(name for name in scores if name not in NOT_OBJECTS)
    return scores.get(region, {}).get(key, float("nan"))


def body_schema(args: argparse.Namespace) -> None:
    th.set_num_threads(args.threads)
    os.makedirs(args.out, exist_ok=True)
    results_path = os.path.join(args.out, "results.json")
    runs = []
    if os.path.exists(results_path):  # a rerun adds the missing (experiment, seed) pairs
        with open(results_path) as file:
            runs = json.load(file)["runs"]
    done = {(run["experiment"], run["seed"]): index for index, run in enumerate(runs)}
    for seed in args.seeds:
        for experiment in args.experiments:
            if (experiment, seed) in done and not args.rescore:
                continue
            run = run_experiment(experiment, seed, args)
            if (experiment, seed) in done:  # rescored: keep the first run's collection and training times
                previous = runs[done[(experiment, seed)]]
                runs[done[(experiment, seed)]] = {**previous, **run, "collect_seconds": previous["collect_seconds"]}
            else:
                runs.append(run)
            with open(results_path, "w") as file:
                json.dump({"args": vars(args), "runs": runs}, file, indent=2)
            with open(os.path.join(args.out, "table.md"), "w") as file:
                file.write(summary_table(runs))
    print(summary_table(runs))


def combined_table(folders: list[str]) -> str:
    """The summary table over the runs of several body-schema output folders (e.g. one per seed)."""
    runs = []
    for folder in folders:
        with open(os.path.join(folder, "results.json")) as file:
            runs += json.load(file)["runs"]
    return summary_table(sorted(runs, key=lambda run: (list(EXPERIMENTS).index(run["experiment"]), run["seed"])))


def add_body_schema_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("--experiments", nargs="+", choices=list(EXPERIMENTS), default=list(EXPERIMENTS))
    parser.add_argument("--seeds", nargs="+", type=int, default=[0, 1, 2])
    parser.add_argument("--size", type=int, default=64)
    parser.add_argument("--steps", type=int, default=40, help="babbling steps recorded per episode")
    parser.add_argument("--train-episodes", type=int, default=16, help="per experiment, split over its conditions")
    parser.add_argument("--eval-episodes", type=int, default=3, help="held-out episodes per condition")
    parser.add_argument("--stride", type=int, default=2, help="every stride-th window of a held-out episode")
    parser.add_argument("--saliency-windows", type=int, default=12, help="per condition")
    parser.add_argument("--updates", type=int, default=800)
    parser.add_argument("--batch-size", type=int, default=16)
    parser.add_argument("--encoder", default="drqv2", help="offline encoder: drqv2, dcgan-unet or tdmpc2")
    parser.add_argument("--features-dim", type=int, default=256)
    parser.add_argument("--context", type=int, default=3)
    parser.add_argument("--horizon", type=int, default=10)
    parser.add_argument("--agent-dim", type=int, default=32)
    parser.add_argument("--decoder-channels", type=int, default=32)
    parser.add_argument("--lr", type=float, default=1e-3)
    parser.add_argument(
        "--target",
        choices=["pixel", "latent"],
        default="pixel",
        help="EF's target: the future frame, or its features (scored through the probe decoder, trained alongside)",
    )
    parser.add_argument("--threads", type=int, default=1)
    parser.add_argument("--out", required=True, help="output folder; a rerun adds the missing runs")
    parser.add_argument("--figure-eight-steps", type=int, default=30, help="held-tool probe, figures/figure8_s*.png")
    parser.add_argument(
        "--rescore", action="store_true", help="score the runs already in --out again from their saved models"
    )


def main(argv: list[str] | None = None) -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    commands = parser.add_subparsers(dest="command", required=True)
    add_body_schema_arguments(commands.add_parser("run", help="train and score: held tool, door, distractor"))
    table = commands.add_parser("table", help="one table from the results.json of several --out folders")
    table.add_argument("folders", nargs="+")
    args = parser.parse_args(argv)
    if args.command == "run":
        body_schema(args)
    else:
        print(combined_table(args.folders), end="")


if __name__ == "__main__":
    main()
