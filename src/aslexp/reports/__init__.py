"""Reports of the imitation wing, above both ``envs`` and ``rl``: tables and curves of imitation
sweeps (``report``: the letters; ``thesis_report``, ``upper_body_report``, ``residual_report``),
the no-learning baselines they rebuild environments for, the two engines side by side
(``engine_agreement``) and what exploration noise costs a trained policy (``noise_cost``).
Each runs as ``python -m aslexp.reports.<name> ...``; the imitate job writes the tables after a sweep."""
