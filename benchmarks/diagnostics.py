"""
What the benchmarks log beside a run that the algorithms do not: SAC's critic on real transitions only and on the
minibatches SAC draws (``CriticDiagnostics``: ``train/critic_loss_real``, ``train/q_real``, ``train/q``, read by
``plot.py``), and the env steps the agent made while a feedback session's answers were awaited
(``AwaitingFeedback``: ``result.json``'s ``steps_awaiting_feedback``). Both draw nothing from the run's random
generators, so a run with them trains exactly as one without.
"""

from typing import Any

import numpy as np
import torch as th
from stable_baselines3.common.callbacks import BaseCallback

from sb3_pride.common.utils import seeded


class CriticDiagnostics(BaseCallback):
    """
    Every ``interval`` steps after pre-training, SAC's critic loss and mean Q(s, a) on a minibatch of real transitions
    only (PEBBLE's and PRIDE's critics compared like for like) and the mean Q on one drawn as SAC's updates draw it
    (mixed in PRIDE), each from this callback's own random generators (NumPy's and torch's global states restored).

    :param interval: env steps between two diagnostics
    :param seed: the seed of its own generators
    """

    model: Any  # a PEBBLE or a PRIDE

    def __init__(self, interval: int = 100, seed: int | None = None):
        super().__init__()
        self.interval, self.rng = interval, np.random.default_rng(seed)

    def _on_step(self) -> bool:
        model = self.model
        if model.phase.pretraining or model.num_timesteps <= model.learning_starts or self.n_calls % self.interval:
            return True
        batch_size = model.minibatch_size(model.batch_size) if hasattr(model, "minibatch_size") else model.batch_size
        critic_loss, q_value = self.critic_on(batch_size, real_only=True)
        self.logger.record_mean("train/critic_loss_real", critic_loss)
        self.logger.record_mean("train/q_real", q_value)
        self.logger.record_mean("train/q", self.critic_on(batch_size, real_only=False)[1])
        return True

    @th.no_grad()
    def critic_on(self, batch_size: int, real_only: bool) -> tuple[float, float]:
        model = self.model
        numpy_state = np.random.get_state()  # SB3's sample() and _get_samples draw from NumPy's global RNG
        with seeded(int(self.rng.integers(2**62)), model.device):
            np.random.seed(int(self.rng.integers(2**32)))
            env = model._vec_normalize_env
            if real_only:
                rows = self.rng.integers(0, model.real_buffer.size(), size=batch_size)
                data = model.replay_rewards.rewrite(model.real_buffer._get_samples(rows, env=env), model.real_buffer, env)
            else:
                data = model.replay_buffer.sample(batch_size, env=env)
            next_actions, next_log_prob = model.actor.action_log_prob(data.next_observations)
            next_q = th.min(th.cat(model.critic_target(data.next_observations, next_actions), dim=1), dim=1, keepdim=True)[0]
            ent_coef = model.ent_coef_tensor if model.log_ent_coef is None else th.exp(model.log_ent_coef)
            # r̂ + γ(1 − d)(min Q_target(s', a') − α log π(a'|s'))
            target = data.rewards + (1 - data.dones) * model.gamma * (next_q - ent_coef * next_log_prob.reshape(-1, 1))
            current = model.critic(data.observations, data.actions)
        np.random.set_state(numpy_state)
        critic_loss = 0.5 * sum(th.nn.functional.mse_loss(q, target) for q in current)
        return float(critic_loss), float(th.cat(current, dim=1).mean())


class AwaitingFeedback(BaseCallback):
    """The env steps made while a published feedback session was open (its answers awaited), over the run."""

    model: Any  # a PEBBLE or a PRIDE

    def __init__(self):
        super().__init__()
        self.steps = 0

    def _on_step(self) -> bool:
        self.steps += self.model.feedback.pending is not None
        return True
