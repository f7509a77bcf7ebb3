from typing import Any, ClassVar, Optional, Union

import numpy as np
from stable_baselines3.common.callbacks import BaseCallback
from stable_baselines3.common.type_aliases import GymEnv
from stable_baselines3.sac.policies import SACPolicy

from sb3_pride.common.buffers import DualReplayBuffer, PreferenceReplayBuffer
from sb3_pride.common.callbacks import DiffusionCallback
from sb3_pride.common.diffusion import ElucidatedDiffusion
from sb3_pride.common.utils import check_positive_ints
from sb3_pride.pebble.pebble import PEBBLE

class PRIDE(PEBBLE):
    """
    PRIDE: Preference-based Reinforcement learning using dIffusion moDEL (Feng, Tenytska, Wang & Peng, 2025).

    PEBBLE plus a diffusion model (Algorithm 1, lines 22–37): every ``diffusion_interval`` (R) env steps, once the
    first reward model exists, an EDM diffusion model (as SynthER) is fitted on the real transitions (s, a, s')
    and generates ``synthetic_samples`` new ones into a separate synthetic buffer; every SAC minibatch is then
    ``round(synthetic_ratio · batch_size)`` synthetic transitions and the rest real ones.

    Synthetic rewards are r̂(s, a) of the current reward model: set at generation and relabeled together with the
    real buffer after every reward update. (The paper relabels the real buffer only, which leaves synthetic
    rewards stale until the next generation.) Terminal flags are modelled only if the real buffer holds a true
    termination by the first retrain (never on DMC or Meta-World, whose episodes only time out).

    Every other parameter is PEBBLE's (and SAC's), with the same defaults; paper-scale diffusion settings (SynthER's: width 1024,
    6 blocks, 100k training steps, 128 sampling steps, 1M samples) are in ``hyperparams/pride.yml``. The defaults
    here are sized for a CPU.

    :param synthetic_ratio: u, the synthetic share of each SAC minibatch, in [0, 1] (paper: 0.5). With 0 the
        diffusion model is never trained and PRIDE trains exactly as PEBBLE
    :param diffusion_interval: R, env steps between diffusion retrain-and-generate (paper: 10k)
    :param synthetic_samples: transitions generated per retrain; they replace the synthetic buffer
    :param synthetic_buffer_size: capacity of the synthetic buffer (default: ``synthetic_samples``)
    :param diffusion_width: width of the denoiser's residual blocks
    :param diffusion_blocks: residual blocks of the denoiser
    :param diffusion_train_steps: gradient steps per retrain
    :param diffusion_sample_steps: Heun sampler steps
    :param diffusion_warm_start: start each retrain from the previous model (SynthER starts from scratch; a warm
        start reaches the same fidelity in fewer steps, which is what makes PRIDE affordable on a CPU)
    :param diffusion_kwargs: any other ``ElucidatedDiffusion`` argument (``dim_t``, ``batch_size``,
        ``learning_rate``, ``sample_batch_size``, ``ema_decay``, ...)
    """

    buffer_class: ClassVar[type[PreferenceReplayBuffer]] = DualReplayBuffer  # type: ignore[assignment]
    replay_buffer: DualReplayBuffer  # type: ignore[assignment]

    def __init__(
        self,
        policy: Union[str, type[SACPolicy]],
        env: Union[GymEnv, str],
        synthetic_ratio: float = 0.5,
        diffusion_interval: int = 10_000,
        synthetic_samples: int = 20_000,
        synthetic_buffer_size: Optional[int] = None,
        diffusion_width: int = 256,
        diffusion_blocks: int = 3,
        diffusion_train_steps: int = 2000,
        diffusion_sample_steps: int = 32,
        diffusion_warm_start: bool = True,
        diffusion_kwargs: Optional[dict[str, Any]] = None,
        replay_buffer_kwargs: Optional[dict[str, Any]] = None,
        _init_setup_model: bool = True,
        **pebble_kwargs: Any,
    ):
        if not 0.0 <= synthetic_ratio <= 1.0:
            raise ValueError(f"synthetic_ratio must be in [0, 1], got {synthetic_ratio}")
        check_positive_ints(
            diffusion_interval=diffusion_interval,
            synthetic_samples=synthetic_samples,
            diffusion_width=diffusion_width,
            diffusion_blocks=diffusion_blocks,
            diffusion_train_steps=diffusion_train_steps,
            diffusion_sample_steps=diffusion_sample_steps,
        )
        if synthetic_buffer_size is not None:
            check_positive_ints(synthetic_buffer_size=synthetic_buffer_size)
        replay_buffer_kwargs = dict(replay_buffer_kwargs or {})
        replay_buffer_kwargs.setdefault("synthetic_buffer_size", synthetic_buffer_size or synthetic_samples)
        replay_buffer_kwargs.setdefault("synthetic_ratio", synthetic_ratio)
        super().__init__(policy, env, replay_buffer_kwargs=replay_buffer_kwargs, _init_setup_model=False, **pebble_kwargs)
        self.synthetic_ratio = synthetic_ratio
        self.diffusion_interval = diffusion_interval
        self.synthetic_samples = synthetic_samples
        self.synthetic_buffer_size = synthetic_buffer_size
        self.diffusion_width = diffusion_width
        self.diffusion_blocks = diffusion_blocks
        self.diffusion_train_steps = diffusion_train_steps
        self.diffusion_sample_steps = diffusion_sample_steps
        self.diffusion_warm_start = diffusion_warm_start
        self.diffusion_kwargs = dict(diffusion_kwargs or {})
        # learning state, saved with the model; the diffusion model is built at the first retrain, when it is
        # known whether terminal flags are part of a transition
        self.model_terminals: Optional[bool] = None
        self.diffusion: Optional[ElucidatedDiffusion] = None
        self.diffusion_retrains = 0
        # the first retrain comes right after the first reward learning
        self.next_diffusion_step = self.next_feedback_step

        if _init_setup_model:
            self._setup_model()

    def _setup_model(self) -> None:
        super()._setup_model()
        if self.model_terminals is not None:  # loading a model that was retrained: rebuild before its weights load
            self._build_diffusion()

    def _shift_schedules(self, steps: int) -> None:
        super()._shift_schedules(steps)
        self.next_diffusion_step = max(0, self.next_diffusion_step + steps)

    @property
    def real_buffer(self) -> PreferenceReplayBuffer:
        """B_real, the agent's own transitions with their true rewards aside."""
        return self.replay_buffer.real

    def _preference_callbacks(self) -> list[BaseCallback]:
        return [*super()._preference_callbacks(), DiffusionCallback(verbose=self.verbose)]

    def train(self, gradient_steps: int, batch_size: int = 64) -> None:
        # Algorithm 1, lines 34–37: each SAC minibatch holds round(u·B) synthetic and B − round(u·B) real
        # transitions (DualReplayBuffer.sample); real only until the first generation
        self.replay_buffer.synthetic_ratio = self.synthetic_ratio
        super().train(gradient_steps, batch_size)
        self.logger.record("train/synthetic_per_batch", self.replay_buffer.n_synthetic(batch_size))

    def relabel(self) -> None:
        """Relabel B_real (Algorithm 1, line 20) and, unlike the paper, B_syn too: r̂ is never stale."""
        super().relabel()
        self.replay_buffer.synthetic.relabel(self.reward_model.predict)

    # the diffusion model's data: flat transition vectors [s, a, s'(, terminal)] -----------------------------
    def _build_diffusion(self) -> None:
        obs_dim, action_dim = self.real_buffer.obs_shape[0], self.real_buffer.action_dim
        dim = 2 * obs_dim + action_dim + int(bool(self.model_terminals))
        options = dict(
            width=self.diffusion_width,
            n_blocks=self.diffusion_blocks,
            train_steps=self.diffusion_train_steps,
            sample_steps=self.diffusion_sample_steps,
            warm_start=self.diffusion_warm_start,
            skip_normalization=(dim - 1,) if self.model_terminals else (),
            seed=self.seed,
            device=self.device,
        )
        self.diffusion = ElucidatedDiffusion(dim, **{**options, **self.diffusion_kwargs})

    def transition_vectors(self) -> np.ndarray:
        """Every real transition as one vector [s, a, s'] (plus the terminal flag where the env terminates)."""
        buffer = self.real_buffer
        n = buffer.size()
        terminals = buffer.dones[:n] * (1.0 - buffer.timeouts[:n])
        if self.model_terminals is None:
            self.model_terminals = bool(terminals.any())
            self._build_diffusion()
        columns = [buffer.observations[:n], buffer.actions[:n], buffer.next_observations[:n]]
        if self.model_terminals:
            columns.append(terminals[..., None])
        vectors = np.concatenate(columns, axis=-1, dtype=np.float32)
        return vectors.reshape(-1, vectors.shape[-1])

    def store_synthetic(self, generated: np.ndarray) -> tuple[np.ndarray, int]:
        """
        Fill B_syn with generated vectors: non-finite ones dropped (and counted), actions clipped to the action
        bounds, terminal flags rounded at 0.5, rewards r̂(s, a).

        :return: the vectors kept (after clipping), how many were dropped
        """
        finite = np.all(np.isfinite(generated), axis=1)
        kept = generated[finite].copy()
        obs_dim, action_dim = self.real_buffer.obs_shape[0], self.real_buffer.action_dim
        actions = kept[:, obs_dim : obs_dim + action_dim]
        np.clip(actions, -1.0, 1.0, out=actions)  # the buffer holds actions scaled to [-1, 1]
        obs, next_obs = kept[:, :obs_dim], kept[:, obs_dim + action_dim : 2 * obs_dim + action_dim]
        if self.model_terminals:
            kept[:, -1] = (kept[:, -1] > 0.5).astype(np.float32)
            dones = kept[:, -1]
        else:
            dones = np.zeros(len(kept), dtype=np.float32)
        rewards = self.reward_model.predict(obs, actions)
        self.replay_buffer.synthetic.replace(obs, actions, next_obs, dones, rewards)
        return kept, int((~finite).sum())

    def _get_torch_save_params(self) -> tuple[list[str], list[str]]:
        state_dicts, variables = super()._get_torch_save_params()
        return ([*state_dicts, "diffusion"] if self.diffusion is not None else state_dicts), variables

    def _excluded_save_params(self) -> list[str]:
        return [*super()._excluded_save_params(), "diffusion"]
