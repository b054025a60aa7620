import numpy as np
import pytest
from stable_baselines3.common.evaluation import evaluate_policy
from stable_baselines3.common.monitor import Monitor

from sb3_ef.envs.toy import ToyAgentEnv
from sb3_ef.tdmpc2 import TDMPC2, TDMPC2EF

SMALL_POLICY = {
    "num_channels": 8,
    "mlp_dim": 128,
    "num_q": 2,
    "planner_kwargs": {"iterations": 3, "num_samples": 64, "num_elites": 8, "num_pi_trajs": 4},
}
EF_KWARGS = {"rollout_hidden_dims": (64,), "decoder_channels": 16}


def random_return(episodes: int, seed: int) -> float:
    """Mean return of uniform random actions on the same episodes the trained agent is evaluated on."""
    env = ToyAgentEnv(size=64, max_episode_steps=50)
    env.action_space.seed(seed)
    returns = []
    for episode in range(episodes):
        env.reset(seed=seed + episode)
        total, done = 0.0, False
        while not done:
            _, reward, terminated, truncated, _ = env.step(env.action_space.sample())
            total += reward
            done = terminated or truncated
        returns.append(total)
    return float(np.mean(returns))


@pytest.mark.slow
@pytest.mark.parametrize("algorithm", [TDMPC2, TDMPC2EF])
def test_learns_to_move_the_toy_agent_to_the_centre(algorithm):
    # Reward: minus the agent's distance to the centre each step. Random actions leave it where it started
    # (about -16 per 50-step episode); moving to the centre and staying there gives about -2.
    kwargs = {"policy_kwargs": SMALL_POLICY}
    if algorithm is TDMPC2EF:
        kwargs = {"babbling_steps": 100, "ef_horizon": 5, "policy_kwargs": {**SMALL_POLICY, "ef_kwargs": EF_KWARGS}}
    model = algorithm(
        "CnnPolicy",
        ToyAgentEnv(size=64, max_episode_steps=50),
        learning_starts=200,
        batch_size=32,
        buffer_size=5000,
        seed=0,
        **kwargs,
    )
    model.learn(2000)
    eval_env = Monitor(ToyAgentEnv(size=64, max_episode_steps=50))
    eval_env.reset(seed=100)
    trained, _ = evaluate_policy(model, eval_env, n_eval_episodes=5, deterministic=True)
    baseline = random_return(episodes=5, seed=100)
    assert trained > baseline + 6.0, (trained, baseline)
