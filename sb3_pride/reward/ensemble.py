"""The reward model r̂: an ensemble of MLPs on (s, a) trained on preferences with the Bradley–Terry loss."""

import itertools
import math
from collections.abc import Callable, Sequence

import numpy as np
import torch as th
from stable_baselines3.common.utils import get_device
from torch import nn
from torch.nn import functional as F

from sb3_pride.reward.options import PseudoLabels, RewardOption


def preference_loss(returns: th.Tensor, labels: th.Tensor) -> th.Tensor:
    """
    Bradley–Terry cross-entropy (Eqs. 1–2): P[σ1 ≻ σ0] = softmax([R̂0, R̂1])[1], with R̂ the sum of r̂ over
    a segment; ``labels`` are the target probabilities μ that σ1 is preferred (0, 1, or 0.5 for "equal").

    :param returns: (..., 2) predicted segment returns
    :param labels: (...) targets in [0, 1]
    :return: mean loss
    """
    log_p = F.log_softmax(returns, dim=-1)
    return -((1.0 - labels) * log_p[..., 0] + labels * log_p[..., 1]).mean()


def check_temporal_crop(temporal_crop: object, segment_length: int | None = None) -> tuple[int, int] | None:
    """
    ``temporal_crop`` as a ``(min_length, max_length)`` tuple of ints, or None (no cropping).

    :param temporal_crop: None or a pair of ints with ``1 <= min_length <= max_length``
    :param segment_length: the labelled segments' length, which ``max_length`` may not exceed (None: not checked)
    :raise ValueError: naming ``temporal_crop`` for anything else
    """
    if temporal_crop is None:
        return None
    if (
        not isinstance(temporal_crop, (tuple, list))
        or len(temporal_crop) != 2
        or any(isinstance(v, (bool, np.bool_)) or not isinstance(v, (int, np.integer)) for v in temporal_crop)
    ):
        raise ValueError(f"temporal_crop must be None or a pair of ints (min_length, max_length), got {temporal_crop!r}")
    min_length, max_length = int(temporal_crop[0]), int(temporal_crop[1])
    if min_length < 1:
        raise ValueError(f"temporal_crop: min_length must be >= 1, got {temporal_crop!r}")
    if min_length > max_length:
        raise ValueError(f"temporal_crop: min_length must be <= max_length, got {temporal_crop!r}")
    if segment_length is not None and max_length > segment_length:
        raise ValueError(
            f"temporal_crop: max_length must be <= segment_length ({segment_length}): a crop lies inside the labelled "
            f"segment, got {temporal_crop!r}"
        )
    return min_length, max_length


def crop_pairs(
    inputs: th.Tensor,
    labels: th.Tensor,
    temporal_crop: tuple[int, int],
    rng: np.random.Generator,
) -> tuple[th.Tensor, th.Tensor, th.Tensor]:
    """
    SURF's temporal cropping of labelled pairs (Park et al., ICLR 2022, "temporal data augmentation"; also QPA,
    Hu et al., ICLR 2024): each pair (σ0, σ1) gets one length L, uniform in ``[min_length, max_length]``, and each of
    its two segments its own start, uniform in ``[0, k - L]``; the pair keeps its label (a preference between the
    segments is assumed to hold between slightly shifted, shorter windows of them). The crops are gathered into
    ``max_length`` steps, the steps past L masked out, so that a cropped return is ``(r̂ · mask).sum(-1)``.

    :param inputs: (..., 2, k, input_dim) a minibatch of pairs
    :param labels: (...) their labels μ
    :param temporal_crop: (min_length, max_length), ``max_length <= k``
    :param rng: draws the lengths and starts
    :return: the cropped inputs (..., 2, max_length, input_dim), the mask of the kept steps (..., 2, max_length)
        (L ones, then zeros; the same L in both segments of a pair) and the labels, unchanged
    """
    min_length, max_length = temporal_crop
    *batch_shape, two, k, input_dim = inputs.shape
    if two != 2 or max_length > k:
        raise ValueError(f"temporal_crop {temporal_crop} needs pairs of segments of >= {max_length} steps, got {inputs.shape}")
    lengths = rng.integers(min_length, max_length + 1, size=(*batch_shape, 1, 1))  # one L per pair
    starts = rng.integers(0, k - lengths + 1, size=(*batch_shape, 2, 1))  # its own start in each segment
    steps = np.arange(max_length)
    # steps past L repeat the crop's last step (any valid row would do: they are masked out)
    index = starts + np.minimum(steps, lengths - 1)  # (..., 2, max_length)
    index_t = th.as_tensor(index, device=inputs.device)
    cropped = th.gather(inputs, -2, index_t.unsqueeze(-1).expand(*index.shape, input_dim))
    mask = th.as_tensor(steps < lengths, dtype=inputs.dtype, device=inputs.device).expand(*index.shape)
    return cropped, mask, labels


class PreferenceDataset:
    """
    The preference dataset D: segment pairs as (s, a) inputs and the teacher's labels μ.

    :param segment_length: steps per segment
    :param input_dim: obs_dim + action_dim
    """

    def __init__(self, segment_length: int, input_dim: int):
        self.inputs = np.zeros((0, 2, segment_length, input_dim), dtype=np.float32)
        self.labels = np.zeros(0, dtype=np.float32)

    def __len__(self) -> int:
        return len(self.labels)

    def add(self, inputs: np.ndarray, labels: np.ndarray) -> None:
        self.inputs = np.concatenate([self.inputs, inputs.astype(np.float32)])
        self.labels = np.concatenate([self.labels, labels.astype(np.float32)])


class EnsembleMLP(nn.Module):
    """
    ``n_members`` independent MLPs evaluated together with batched matrix products (one call per layer for the
    whole ensemble instead of one per member and layer). Each layer is initialized like ``nn.Linear``.

    :param n_members: ensemble size
    :param input_dim: input size
    :param net_arch: hidden layer sizes
    :param output_dim: output size
    :param output_activation: applied to the output (the reward model's tanh; None: linear)
    :param hidden_activation: applied after every hidden layer (the reward model's LeakyReLU)
    """

    def __init__(
        self,
        n_members: int,
        input_dim: int,
        net_arch: tuple[int, ...],
        output_dim: int = 1,
        output_activation: Callable[[th.Tensor], th.Tensor] | None = th.tanh,
        hidden_activation: Callable[[th.Tensor], th.Tensor] = F.leaky_relu,
    ):
        super().__init__()
        self.output_activation = output_activation
        self.hidden_activation = hidden_activation
        dims = [input_dim, *net_arch, output_dim]
        self.weights = nn.ParameterList()
        self.biases = nn.ParameterList()
        for fan_in, fan_out in itertools.pairwise(dims):
            bound = 1.0 / math.sqrt(fan_in)  # nn.Linear's default: U(-1/sqrt(fan_in), 1/sqrt(fan_in))
            self.weights.append(nn.Parameter(th.empty(n_members, fan_in, fan_out).uniform_(-bound, bound)))
            self.biases.append(nn.Parameter(th.empty(n_members, 1, fan_out).uniform_(-bound, bound)))

    def hidden(self, x: th.Tensor) -> th.Tensor:
        """(members, N, input_dim) -> (members, N, last hidden size): the hidden layers alone (the encoder)."""
        for weight, bias in zip(self.weights[:-1], self.biases[:-1], strict=True):
            x = self.hidden_activation(th.baddbmm(bias, x, weight))
        return x

    def forward(self, x: th.Tensor) -> th.Tensor:
        """(members, N, input_dim) -> (members, N, output_dim): ``hidden_activation`` after hidden layers, then
        ``output_activation``."""
        last = len(self.weights) - 1
        for i, (weight, bias) in enumerate(zip(self.weights, self.biases, strict=True)):
            x = th.baddbmm(bias, x, weight)
            if i < last:
                x = self.hidden_activation(x)
            elif self.output_activation is not None:
                x = self.output_activation(x)
        return x


class RewardEnsemble(nn.Module):
    """
    PEBBLE's reward model: ``n_members`` MLPs r̂_m(s, a) with a tanh output (per-step reward in [-1, 1]).
    ``predict`` is the ensemble mean; members disagree on what the labels do not pin down, which the
    "disagreement" and "entropy" query selections exploit.

    :param obs_dim: observation size
    :param action_dim: action size
    :param n_members: ensemble size (PEBBLE: 3)
    :param net_arch: hidden layers of each member (PEBBLE: 3 × 256)
    :param learning_rate: Adam step size (PEBBLE: 3e-4)
    :param device: torch device
    """

    def __init__(
        self,
        obs_dim: int,
        action_dim: int,
        n_members: int = 3,
        net_arch: tuple[int, ...] = (256, 256, 256),
        learning_rate: float = 3e-4,
        device: th.device | str = "auto",
    ):
        super().__init__()
        if n_members < 1:
            raise ValueError(f"ensemble_size must be >= 1, got {n_members}")
        self.input_dim = obs_dim + action_dim
        self.n_members = n_members
        self.members = EnsembleMLP(n_members, self.input_dim, tuple(net_arch))
        self.device = get_device(device)
        self.to(self.device)
        self.optimizer = th.optim.Adam(self.parameters(), lr=learning_rate)

    def forward(self, inputs: th.Tensor) -> th.Tensor:
        """Per-member rewards of the same inputs: (..., input_dim) -> (members, ..., 1)."""
        flat = inputs.reshape(1, -1, self.input_dim).expand(self.n_members, -1, -1)
        return self.members(flat).reshape(self.n_members, *inputs.shape[:-1], 1)

    @th.no_grad()
    def predict(self, observations: np.ndarray, actions: np.ndarray) -> np.ndarray:
        """r̂(s, a): the ensemble mean, numpy in and out, shape (...) for inputs of shape (..., dim)."""
        inputs = th.as_tensor(np.concatenate([observations, actions], axis=-1), dtype=th.float32, device=self.device)
        return self(inputs).mean(dim=0).squeeze(-1).cpu().numpy()

    @th.no_grad()
    def disagreement(self, observations: np.ndarray, actions: np.ndarray) -> np.ndarray:
        """The members' standard deviation of r̂(s, a): how unsure the ensemble is, shape (...)."""
        inputs = th.as_tensor(np.concatenate([observations, actions], axis=-1), dtype=th.float32, device=self.device)
        return self(inputs).std(dim=0).squeeze(-1).cpu().numpy()

    @th.no_grad()
    def member_segment_returns(self, inputs: np.ndarray, batch_size: int = 256) -> th.Tensor:
        """
        Each member's return of each segment: (n, 2, k, input_dim) -> (members, n, 2), the sum of r̂ over the k steps;
        any k (r̂ is per step: segments shorter than the labelled ones, e.g. crops, are shorter sums).
        """
        chunks = [
            self(th.as_tensor(inputs[i : i + batch_size], dtype=th.float32, device=self.device)).sum(dim=(-2, -1))
            for i in range(0, len(inputs), batch_size)
        ]
        return th.cat(chunks, dim=1).cpu()

    def pseudo_label_loss(
        self,
        unlabeled: th.Tensor,
        n_labeled: int,
        pseudo_labels: PseudoLabels,
        rng: np.random.Generator,
        temporal_crop: tuple[int, int] | None,
    ) -> th.Tensor:
        """
        SURF's unlabelled loss for one minibatch (summed over members, as the labelled one): ``ratio`` × ``n_labeled``
        unlabelled pairs per member, each member's own confident pseudo-labels ŷ = 1[P̂_m > 0.5] where
        max(P̂_m, 1 − P̂_m) > τ, the Bradley–Terry loss on them (cropped when cropping) times λ.
        """
        n = pseudo_labels.ratio * n_labeled
        idx = th.as_tensor(rng.integers(0, len(unlabeled), size=(self.n_members, n)), device=self.device)
        batch = unlabeled[idx]  # (members, n, 2, k, d)
        with th.no_grad():
            whole = self.members(batch.reshape(self.n_members, -1, self.input_dim)).reshape(*batch.shape[:-1])
            p = th.softmax(whole.sum(dim=-1), dim=-1)[..., 1]  # (members, n): each member's own P̂
            targets = (p > 0.5).float()
            confident = (th.maximum(p, 1 - p) > pseudo_labels.threshold).float()
        if temporal_crop is not None:
            batch, mask, _ = crop_pairs(batch, targets, temporal_crop, rng)
        rewards = self.members(batch.reshape(self.n_members, -1, self.input_dim)).reshape(*batch.shape[:-1])
        if temporal_crop is not None:
            rewards = rewards * mask
        log_p = F.log_softmax(rewards.sum(dim=-1), dim=-1)
        per_pair = -((1.0 - targets) * log_p[..., 0] + targets * log_p[..., 1])
        # mean over the drawn pairs, the unconfident ones counting as 0 (SURF's masked mean), summed over members
        return pseudo_labels.weight * (per_pair * confident).mean(dim=1).sum()

    @th.no_grad()
    def label_divergence(self, inputs: th.Tensor, labels: th.Tensor, batch_size: int = 256) -> np.ndarray:
        """
        ℓ per labelled pair: the cross-entropy of its label μ under the members' mean P̂[σ1 ≻ σ0] (RIME's KL
        divergence between the label and the prediction, up to the label's own entropy, 0 for strict labels).
        """
        probabilities = []
        for start in range(0, len(labels), batch_size):
            returns = self(inputs[start : start + batch_size]).sum(dim=(-2, -1))  # (members, b, 2)
            probabilities.append(th.softmax(returns, dim=-1)[..., 1].mean(dim=0))
        p = th.cat(probabilities).clamp(1e-6, 1 - 1e-6) if probabilities else th.zeros(0, device=self.device)
        return (-((1 - labels) * th.log1p(-p) + labels * th.log(p))).cpu().numpy()

    def train_epochs(
        self,
        dataset: PreferenceDataset,
        max_epochs: int,
        batch_size: int = 128,
        target_accuracy: float = 0.97,
        rng: np.random.Generator | None = None,
        temporal_crop: tuple[int, int] | None = None,
        options: Sequence[RewardOption] = (),
    ) -> tuple[float, float, int]:
        """
        Train on D for up to ``max_epochs`` epochs, each member on its own shuffling of D (the loss is summed
        over members); stop early once the training accuracy of an epoch exceeds ``target_accuracy`` (PEBBLE; 1.0
        or more: never, every epoch runs). Accuracy counts pairs with a strict label (0 or 1) that the member ranks
        the same way (on the cropped returns when cropping, as SURF does).

        :param temporal_crop: SURF's temporal cropping (``crop_pairs``): at every minibatch each member sees each
            pair cropped to a random length in ``[min_length, max_length]``, with its own random start in each
            segment. None: whole segments (PEBBLE)
        :param options: the reward-learning options on (``RewardOption``), in order: each may choose the pairs and
            labels an epoch trains on (RIME's ``RobustLabels``) and add a loss to each minibatch's (SURF's
            ``PseudoLabels``)
        :return: (last epoch's mean loss per member, its accuracy, epochs run)
        """
        rng = rng if rng is not None else np.random.default_rng()
        temporal_crop = check_temporal_crop(temporal_crop, dataset.inputs.shape[2])
        inputs = th.as_tensor(dataset.inputs, device=self.device)
        labels = th.as_tensor(dataset.labels, device=self.device)
        n = len(labels)
        loss_value, accuracy, epoch = float("nan"), 0.0, 0
        given = labels
        for epoch in range(1, max_epochs + 1):  # noqa: B007 (returned: the epochs run)
            used, labels = np.arange(n), given
            for option in options:
                chosen = option.choose_labels(self, inputs, labels, dataset.labels)
                if chosen is not None:
                    used, labels = chosen
            orders = th.as_tensor(
                np.stack([used[rng.permutation(len(used))] for _ in range(self.n_members)]), device=self.device
            )
            total_loss, correct, counted = 0.0, 0.0, 0.0
            for start in range(0, len(used), batch_size):
                idx = orders[:, start : start + batch_size]  # (members, b): each member its own minibatch
                batch, batch_labels = inputs[idx], labels[idx]  # (members, b, 2, k, d), (members, b)
                if temporal_crop is not None:
                    batch, mask, batch_labels = crop_pairs(batch, batch_labels, temporal_crop, rng)
                rewards = self.members(batch.reshape(self.n_members, -1, self.input_dim)).reshape(*batch.shape[:-1])
                if temporal_crop is not None:
                    rewards = rewards * mask  # a cropped segment's return sums r̂ over its L kept steps
                returns = rewards.sum(dim=-1)  # (members, b, 2): R̂0, R̂1 (Eq. 1)
                # Eq. 2 for each member, summed over members
                loss = preference_loss(returns, batch_labels) * self.n_members
                for option in options:
                    extra = option.extra_loss(self, idx.shape[1], rng, temporal_crop)
                    if extra is not None:
                        loss = loss + extra
                self.optimizer.zero_grad()
                loss.backward()
                self.optimizer.step()
                strict = batch_labels != 0.5
                predicted = (returns[..., 1] > returns[..., 0]).float()
                correct += float(((predicted == batch_labels) & strict).sum())
                counted += float(strict.sum())
                total_loss += loss.item() * idx.shape[1] / self.n_members
            loss_value = total_loss / max(len(used), 1)
            accuracy = correct / max(counted, 1.0)
            if accuracy > target_accuracy:
                break
        return loss_value, accuracy, epoch
