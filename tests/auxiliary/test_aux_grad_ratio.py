"""``train/aux_grad_ratio`` on the hosts whose auxiliary step is separate from their own update (SAC-EF, TD3-EF,
TQC-EF, CURL): the auxiliary loss's encoder-gradient norm over the one the critic's loss left at its step, on the
first update and one in every ``AUX_GRAD_RATIO_EVERY``."""

from __future__ import annotations

import math

import pytest
import torch as th

from sb3_ef import SACEF, TD3EF, TQCEF
from sb3_ef.auxiliary.host import gradient_norm, gradient_norm_ratio
from tests.curl.test_curl_algorithm import make as make_curl
from tests.sb3_hosts.test_ef_hosts import LEARNING_STARTS, make

pytestmark = pytest.mark.filterwarnings("ignore:learning_starts=.* no gradient update will run")


def ratio_of_first_update(model) -> float | None:
    """Fill the buffer without updates, then one update (the first, whose ratio is computed): the logged ratio."""
    model.learn(LEARNING_STARTS)
    assert model._n_updates == 0
    model.train(gradient_steps=1, batch_size=8)
    return model.logger.name_to_value.get("train/aux_grad_ratio")


@pytest.mark.parametrize("host", [SACEF, TD3EF, TQCEF])
def test_the_ratio_is_the_ef_steps_gradient_over_the_critics_and_scales_with_beta(host):
    ratio = ratio_of_first_update(make(host, beta=1.0))
    assert ratio is not None and math.isfinite(ratio) and ratio > 0
    # Same seed: the host's update is the same, EF's loss (and so its encoder gradient) ten times larger.
    assert ratio_of_first_update(make(host, beta=10.0)) == pytest.approx(10 * ratio, rel=1e-4)


def test_the_ratio_is_left_out_of_updates_that_do_not_compute_it():
    model = make(SACEF)
    model.learn(LEARNING_STARTS)
    model._n_updates = 1  # the next update is the second: not due
    model.logger.name_to_value.clear()
    model.train(gradient_steps=1, batch_size=8)
    assert "train/ef_loss" in model.logger.name_to_value
    assert "train/aux_grad_ratio" not in model.logger.name_to_value
    assert not model.critic.optimizer._optimizer_step_pre_hooks  # the reading hook is removed after train


def test_curl_logs_the_contrastive_steps_gradient_over_the_critics():
    model = make_curl()
    model.learn(12)
    model.train(gradient_steps=1, batch_size=8)
    ratio = model.logger.name_to_value.get("train/aux_grad_ratio")
    assert ratio is not None and math.isfinite(ratio) and ratio > 0


def test_gradient_norm_reads_what_the_last_backward_left():
    first, second = th.nn.Parameter(th.ones(3)), th.nn.Parameter(th.ones(4))
    (2 * first.sum() + second.sum()).backward()
    assert float(gradient_norm([first, second])) == pytest.approx(math.sqrt(3 * 4 + 4))
    assert float(gradient_norm_ratio([second], th.tensor(4.0))) == pytest.approx(0.5)
