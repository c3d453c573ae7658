"""Learning layer of the imitation wing: PPO with torchrl (``ppo``), many environments per learner
(``vector``), the agent's model (``policy``), checkpoints (``checkpoint``), deterministic evaluation
and baselines (``evaluate``) and figures/tables (``report``)."""
