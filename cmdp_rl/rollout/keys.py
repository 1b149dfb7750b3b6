"""Every TensorDict key the toolkit reads or writes. A batch ``[num_envs, time]`` follows torchrl's layout:
what the agent saw and did at step t at the root, what the env returned under ``"next"``. Reward and cost
are twins: whatever one has (critic value, advantage, value target, episode sum), the other has too.
"""

OBS = "observation"
ACTION = "action"
LOG_PROB = "action_log_prob"  # torchrl's ProbabilisticActor writes this name
LOC = "loc"
SCALE = "scale"
LOGITS = "logits"  # a categorical actor's parameters (gymnasium Discrete actions)
IS_INIT = "is_init"  # True on the first step of an episode (torchrl's InitTracker convention)

NEXT = "next"
REWARD = "reward"
COST = "cost"
DONE = "done"
TERMINATED = "terminated"
TRUNCATED = "truncated"

# Running undiscounted sums of the episode so far, under "next" every step (where DONE: the episode's totals).
EPISODE_RETURN = "episode_return"
EPISODE_COST = "episode_cost"
EPISODE_LENGTH = "episode_length"

# Critic outputs, GAE outputs: reward side and cost side.
VALUE = "state_value"
COST_VALUE = "cost_value"
ADVANTAGE = "advantage"
COST_ADVANTAGE = "cost_advantage"
VALUE_TARGET = "value_target"
COST_VALUE_TARGET = "cost_value_target"
# What each critic signal is called in a batch: (reward or cost entry, value, advantage, value target).
SIGNALS = {
    "reward": (REWARD, VALUE, ADVANTAGE, VALUE_TARGET),
    "cost": (COST, COST_VALUE, COST_ADVANTAGE, COST_VALUE_TARGET),
}
# The advantage the policy loss reads: A_r, (A_r - lambda A_c) or (A_r - lambda A_c)/(1 + lambda).
POLICY_ADVANTAGE = "policy_advantage"

# --- What a history-dependent policy reads and carries (policies/recurrent.py, transformer.py) ---
# The previous step's action and cost at the root when the policy reads them; under "next", this step's.
PREV_ACTION = "prev_action"
PREV_COST = "prev_cost"
# Recurrent state of each network (torchrl LSTMModule/GRUModule; a GRU has no cell), written under "next"
# and carried to the next step's root by the collector (rollout/collector.PolicyMemory).
ACTOR_HIDDEN = "actor_hidden"
ACTOR_CELL = "actor_cell"
CRITIC_HIDDEN = "critic_hidden"
CRITIC_CELL = "critic_cell"
COST_CRITIC_HIDDEN = "cost_critic_hidden"
COST_CRITIC_CELL = "cost_critic_cell"
# The transformer's state: the raw tokens (observation, previous action, previous cost) of the
# K - 1 steps before this one, oldest first, and which of them belong to the current episode.
HISTORY = "history"
HISTORY_MASK = "history_mask"
# Intermediate entries inside one network's forward pass; never stored in a batch.
NET_INPUT = "net_input"
FEATURES = "features"
# deploy.policy=mixture: the member actor each env row follows, drawn at an episode's start (deploy/mixture.py).
MIXTURE_MEMBER = "mixture_member"
