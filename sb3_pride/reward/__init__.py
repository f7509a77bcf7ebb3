"""
Rewards that outlive the run: r̂ saved on its own (``LearnedReward``), fitted from journals alone (``fit_reward``),
given to any SB3 algorithm (``LearnedRewardWrapper``, ``VecLearnedReward``) and shown beside the true reward
(``reward_report``). The command line: ``python -m sb3_pride.reward fit|report ...``.
"""

from sb3_pride.reward.learned_reward import LearnedReward
from sb3_pride.reward.fit import FitReport, fit_reward, preference_accuracy
from sb3_pride.reward.report import EpisodeRewards, episode_rewards, reward_report
from sb3_pride.reward.wrappers import LearnedRewardWrapper, RewardNormalizer, VecLearnedReward

__all__ = [
    "EpisodeRewards",
    "FitReport",
    "LearnedReward",
    "LearnedRewardWrapper",
    "RewardNormalizer",
    "VecLearnedReward",
    "episode_rewards",
    "fit_reward",
    "preference_accuracy",
    "reward_report",
]
