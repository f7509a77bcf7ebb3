"""
Self-supervised pre-training of the reward model's encoder on the agent's transitions, from REED (Metcalf et al.,
"Rewards Encoding Environment Dynamics Improves Preference-based Reinforcement Learning", CoRL 2023).
"""

import math
from dataclasses import dataclass
from typing import TYPE_CHECKING, Any, ClassVar

import numpy as np
import torch as th
from torch.nn import functional as F

from sb3_pride.common.queries import stored_transitions
from sb3_pride.reward.ensemble import EnsembleMLP, RewardEnsemble
from sb3_pride.reward.options import RewardOption

if TYPE_CHECKING:
    from sb3_pride.reward.learner import RewardLearner
    from sb3_pride.reward.options import LearningData

CONSISTENCY_OPTIMIZERS = ("adam", "sgd")


@dataclass
class DynamicsConsistency(RewardOption):
    """
    REED's self-future consistency (Metcalf et al., CoRL 2023, §4): before each feedback session's reward learning,
    the reward model's encoder is trained on the agent's transitions (s, a, s') to predict the representation of the
    next state from that of the state and action, with SimSiam's loss (a negative cosine similarity, the target
    projection held fixed), so that r̂ starts from features that encode the environment's dynamics and the labels only
    have to teach the reward head. It needs no labels: every stored transition is a training example.

    Here the encoder is each member's hidden layers: z(s, a) is the member's last hidden layer. REED's reward network
    embeds the state and the action apart before its trunk, and the target is the state embedding of s'; the members
    here take [s, a] in one first layer, so the representation of a state, e(s), is that layer applied to the state
    alone (the state's part of its weights, its bias, the hidden activation): the same weights r̂ uses, though r̂ itself
    never computes e. A member's next-state predictor (one linear layer, z → e) is followed by a projector and a
    predictor of two layers each with a layer norm (without learnt scale and shift) on their outputs: REED's "mosaic"
    heads, which REED uses for image observations (its state network has a one-layer projector and a batch-normed
    predictor); the batch norm at the projector's input is left out. Each member trains on its own minibatches.

    REED's settings: 1 epoch over the replay buffer before every reward update, batch 128, learning rate 3e-4, SGD,
    a new optimizer at each update, on a random 80% of the buffer. Here the default optimizer is Adam, made once (its
    moments are kept across feedback sessions and saved with the model), a separate one from the reward model's over
    the encoder it shares with it, and a pass takes every stored transition up to ``max_transitions`` (a random
    choice of them beyond). ``optimizer="sgd"`` is REED's (``benchmarks/results/reward_bench_consistency.md``
    compares the two).

    :param epochs: passes over the transitions before each reward update
    :param batch_size: transitions per minibatch
    :param learning_rate: step size of the consistency optimizer
    :param optimizer: "adam" or "sgd"
    :param projection_size: size of the projections compared
    :param hidden_size: hidden size of the projector and the predictor
    :param max_transitions: the most transitions one pass uses (a random choice of them when the buffer holds more)
    """

    epochs: int = 1
    batch_size: int = 128
    learning_rate: float = 3e-4
    optimizer: str = "adam"
    projection_size: int = 128
    hidden_size: int = 256
    max_transitions: int = 50_000

    def __post_init__(self) -> None:
        for name in ("epochs", "batch_size", "projection_size", "hidden_size", "max_transitions"):
            value = getattr(self, name)
            if isinstance(value, bool) or not isinstance(value, int) or value < 1:
                raise ValueError(f"dynamics_consistency: {name} must be an integer >= 1, got {value!r}")
        rate = self.learning_rate
        if isinstance(rate, bool) or not isinstance(rate, (int, float)) or not 0 < rate < math.inf:
            raise ValueError(f"dynamics_consistency: learning_rate must be a finite number > 0, got {rate!r}")
        if self.optimizer not in CONSISTENCY_OPTIMIZERS:
            expected = CONSISTENCY_OPTIMIZERS
            raise ValueError(f"dynamics_consistency: optimizer must be one of {expected}, got {self.optimizer!r}")

    needs_transitions: ClassVar[bool] = True

    def setup(self, learner: "RewardLearner") -> None:
        """REED's heads on the learner's ensemble (``ConsistencyModel``), saved with the model as ``consistency``."""
        learner.consistency = ConsistencyModel(learner.ensemble, learner.obs_dim, self)

    def prepare(self, learner: "RewardLearner", data: "LearningData") -> None:
        """``epochs`` passes over the stored transitions (at most ``max_transitions``) before the labels are learned."""
        assert data.buffer is not None and learner.consistency is not None  # needs_transitions; made by setup
        transitions = stored_transitions(data.buffer, data.rng, self.max_transitions)
        self.loss = learner.consistency.train_epochs(*transitions, data.rng)

    def finish(self) -> dict[str, Any]:
        return {"consistency_loss": getattr(self, "loss", None)}


class ConsistencyModel(th.nn.Module):
    """
    The heads of REED's self-future consistency on a ``RewardEnsemble``'s members (``DynamicsConsistency``): the
    members' hidden layers are shared with r̂ (they are the reward model's own parameters, trained by both losses);
    the heads are this module's. Its optimizer steps the heads and the members' hidden layers, never the reward head.

    :param reward_model: the ensemble whose encoder is trained
    :param obs_dim: observation size (the first ``obs_dim`` inputs of a member are the state)
    :param settings: the consistency settings
    """

    def __init__(self, reward_model: RewardEnsemble, obs_dim: int, settings: DynamicsConsistency):
        super().__init__()
        members = reward_model.members
        if len(members.weights) < 2:
            raise ValueError(
                "dynamics_consistency needs a reward model with at least one hidden layer (reward_kwargs: net_arch)"
            )
        self.members = [members]  # a list: the reward model's parameters are not this module's (nor saved with it)
        self.obs_dim = obs_dim
        self.settings = settings
        n = reward_model.n_members
        state_size, last_hidden = members.weights[0].shape[-1], members.weights[-1].shape[1]
        hidden, projection = (settings.hidden_size,), settings.projection_size
        self.next_state_predictor = EnsembleMLP(n, last_hidden, (), state_size, output_activation=None)
        self.projector = EnsembleMLP(n, state_size, hidden, projection, output_activation=None, hidden_activation=F.relu)
        self.predictor = EnsembleMLP(n, projection, hidden, projection, output_activation=None, hidden_activation=F.relu)
        self.to(reward_model.device)
        encoder = [*members.weights[:-1], *members.biases[:-1]]
        parameters = [*self.parameters(), *encoder]
        if settings.optimizer == "sgd":
            self.optimizer: th.optim.Optimizer = th.optim.SGD(parameters, lr=settings.learning_rate)
        else:
            self.optimizer = th.optim.Adam(parameters, lr=settings.learning_rate)

    def project(self, embedding: th.Tensor) -> th.Tensor:
        """REED's mosaic projector: ReLU, two layers, layer norm."""
        projected = self.projector(F.relu(embedding))
        return F.layer_norm(projected, projected.shape[-1:])

    def loss(self, observations: th.Tensor, actions: th.Tensor, next_observations: th.Tensor) -> th.Tensor:
        """
        SimSiam's loss per member, summed over members: −cos(p, sg(z)) with p = predictor(projector(W z(s, a))) and
        z = projector(e(s')), on (members, b, ·) batches.
        """
        (members,) = self.members
        inputs = th.cat([observations, actions], dim=-1)
        prediction = self.project(self.next_state_predictor(members.hidden(inputs)))
        prediction = self.predictor(F.relu(prediction))
        prediction = F.layer_norm(prediction, prediction.shape[-1:])
        with th.no_grad():
            weight, bias = members.weights[0][:, : self.obs_dim], members.biases[0]
            target = self.project(members.hidden_activation(th.baddbmm(bias, next_observations, weight)))
        return -F.cosine_similarity(prediction, target, dim=-1).mean(dim=1).sum()

    def train_epochs(
        self,
        observations: np.ndarray,
        actions: np.ndarray,
        next_observations: np.ndarray,
        rng: np.random.Generator,
    ) -> float:
        """
        ``epochs`` passes over (a random choice of at most ``max_transitions`` of) the transitions, each member on its
        own shuffling; returns the last pass's mean loss per member (−1 is perfect consistency).
        """
        n = len(observations)
        if n == 0:
            return float("nan")
        chosen = rng.choice(n, self.settings.max_transitions, replace=False) if n > self.settings.max_transitions else None
        device = self.members[0].weights[0].device
        columns = [
            th.as_tensor(column if chosen is None else column[chosen], dtype=th.float32, device=device)
            for column in (observations, actions, next_observations)
        ]
        size, n_members, batch_size = len(columns[0]), self.next_state_predictor.weights[0].shape[0], self.settings.batch_size
        for group in self.optimizer.param_groups:  # the settings' rate, also where a loaded optimizer saved another
            group["lr"] = self.settings.learning_rate
        loss_value = float("nan")
        for _ in range(self.settings.epochs):
            orders = th.as_tensor(np.stack([rng.permutation(size) for _ in range(n_members)]), device=device)
            total = 0.0
            for start in range(0, size, batch_size):
                idx = orders[:, start : start + batch_size]  # (members, b)
                loss = self.loss(*(column[idx] for column in columns))
                self.optimizer.zero_grad()
                loss.backward()
                self.optimizer.step()
                total += loss.item() * idx.shape[1] / n_members
            loss_value = total / size
        return loss_value
