"""zoo_configs/curl.yml against the CURL paper's DMControl table and the authors' train.py."""

from __future__ import annotations

from sb3_ef.zoo.config import default_config_path, load_config, select_entry

#: The paper's action repeats (cartpole 8; finger-spin, walker-walk 2; 4 otherwise), extended by domain.
ACTION_REPEATS = {"cartpole": 8, "finger": 2, "walker": 2}
#: Every entry's settings (train.py and the paper's table).
SHARED = {
    "policy": "CnnPolicy",
    "crop_size": 84,
    "buffer_size": 100_000,
    "learning_starts": 1000,
    "tau": 0.01,
    "target_update_interval": 2,
    "actor_update_interval": 2,
    "encoder_tau": 0.05,
    "gamma": 0.99,
    "train_freq": 1,
    "gradient_steps": 1,
    "ent_coef": "auto_0.1",
    "alpha_learning_rate": 1e-4,
    "alpha_beta": 0.5,
    "policy_kwargs": "dict(net_arch=[1024, 1024])",
}


def test_every_entry_has_the_authors_settings_and_the_papers_per_task_values():
    config = load_config(default_config_path("curl"))
    for env_id in (key for key in config if key != "default"):
        entry = select_entry(config, env_id)
        assert {key: entry.get(key) for key in SHARED} == SHARED, env_id
        assert entry["env_kwargs"]["size"] == 100, env_id
        cheetah = env_id == "dmc/cheetah-run-v0"
        assert (entry["learning_rate"], entry["batch_size"]) == ((2e-4, 512) if cheetah else (1e-3, 128)), env_id
        suite, task = env_id.split("/")
        if suite != "dmc":
            assert entry["env_kwargs"]["action_repeat"] == 2, env_id
            continue
        repeat = ACTION_REPEATS.get(task.split("-")[0], 4)
        assert entry["env_kwargs"]["action_repeat"] == repeat, env_id
        frames = 500_000 if task in ("cartpole-swingup-v0", "ball-in-cup-catch-v0") else 1_000_000
        assert entry["n_timesteps"] * repeat == frames, env_id
