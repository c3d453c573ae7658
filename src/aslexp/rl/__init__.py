"""Learning layer of the imitation wing: PPO with torchrl (``ppo``), many environments per learner
(``vector``), the agent's model (``policy``), checkpoints (``checkpoint``), deterministic evaluation
and baselines (``evaluate``). It imports no environment: it takes any env with the
``ImitationEnv`` interface; the reports that build environments live in :mod:`aslexp.reports`."""
