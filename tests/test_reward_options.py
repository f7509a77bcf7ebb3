"""A reward-learning option written outside the package plugs into the reward learner's training loop: registered by
name, turned on through ``reward_kwargs``, its hooks called with what the built-ins get, its figures logged."""

from dataclasses import dataclass
from typing import Any

import numpy as np
import pandas as pd
import pytest
import torch as th
from stable_baselines3.common.logger import configure

from sb3_pride import PEBBLE
from sb3_pride.reward.options import REWARD_OPTIONS, RewardOption, register_reward_option
from sb3_pride.common.utils import merge_kwargs


@dataclass
class WeightDecay(RewardOption):
    """A user's option: an L2 penalty on r̂'s weights added to every minibatch's loss."""

    weight: float = 1.0
    calls: dict = None  # type: ignore[assignment]

    def __post_init__(self) -> None:
        if not self.weight > 0:
            raise ValueError(f"weight_decay: weight must be > 0, got {self.weight!r}")
        self.calls = {"setup": 0, "prepare": 0, "choose_labels": 0, "extra_loss": 0}

    def setup(self, learner) -> None:
        self.calls["setup"] += 1

    def prepare(self, learner, data) -> None:
        assert len(data.preferences) > 0 and data.buffer is not None and data.queries is not None  # what REED and SURF get
        assert isinstance(data.rng, np.random.Generator)
        self.calls["prepare"] += 1

    def choose_labels(self, ensemble, inputs, labels, given):
        self.calls["choose_labels"] += 1
        return None  # every pair as given

    def extra_loss(self, ensemble, n_pairs, rng, temporal_crop) -> th.Tensor:
        self.calls["extra_loss"] += 1
        return self.weight * sum((w**2).sum() for w in ensemble.members.weights)

    def finish(self) -> dict[str, Any]:
        return {"weight_norm": float(self.calls["extra_loss"])}


@pytest.fixture
def weight_decay():
    register_reward_option("weight_decay", WeightDecay)
    yield
    del REWARD_OPTIONS["weight_decay"]


def weight_norm(model: PEBBLE) -> float:
    return float(sum((w.detach() ** 2).sum() for w in model.reward_model.members.weights))


@pytest.mark.slow
def test_an_option_of_the_users_own_plugs_into_the_training_loop(weight_decay, tiny_kwargs, tmp_path):
    models = {}
    for on in (False, True):
        kwargs = merge_kwargs(tiny_kwargs, dict(reward_kwargs=dict(weight_decay={"weight": 1.0} if on else False)))
        model = PEBBLE("MlpPolicy", "Pendulum-v1", seed=0, **kwargs)
        model.set_logger(configure(str(tmp_path / str(on)), ["csv"]))
        model.learn(1000)
        models[on] = model
    option = models[True].reward_learner.options["weight_decay"]
    assert option.calls["setup"] == 1 and option.calls["prepare"] == models[True].phase.sessions >= 2
    assert option.calls["choose_labels"] >= option.calls["prepare"] and option.calls["extra_loss"] > option.calls["prepare"]
    assert "weight_decay" not in models[False].reward_learner.options
    assert weight_norm(models[True]) < 0.9 * weight_norm(models[False])  # the loss it added was trained on
    progress = pd.read_csv(tmp_path / "True" / "progress.csv")
    assert progress["reward_model/weight_norm"].notna().any()  # its figures are logged beside the built-ins'


def test_a_users_option_is_checked_like_the_built_ins(weight_decay, tiny_kwargs):
    with pytest.raises(ValueError, match="weight_decay: weight must be > 0"):
        PEBBLE("MlpPolicy", "Pendulum-v1", **merge_kwargs(tiny_kwargs, dict(reward_kwargs=dict(weight_decay={"weight": 0}))))
    with pytest.raises(ValueError, match="weight_decay: unknown settings \\['wieght'\\]"):
        PEBBLE("MlpPolicy", "Pendulum-v1", **merge_kwargs(tiny_kwargs, dict(reward_kwargs=dict(weight_decay={"wieght": 1}))))


def test_the_built_ins_are_registered_the_same_way_and_bad_registrations_are_refused():
    assert list(REWARD_OPTIONS)[:4] == ["dynamics_consistency", "pseudo_labels", "robust_labels", "exploration_bonus"]
    assert all(issubclass(option, RewardOption) for option in REWARD_OPTIONS.values())
    with pytest.raises(ValueError, match="'epochs' is a setting of RewardLearner itself"):
        register_reward_option("epochs", WeightDecay)
    with pytest.raises(TypeError, match="must be a RewardOption subclass"):
        register_reward_option("mine", dict)  # type: ignore[arg-type]
    with pytest.raises(ValueError, match="'robust_labels' is already RobustLabels"):
        register_reward_option("robust_labels", WeightDecay)
