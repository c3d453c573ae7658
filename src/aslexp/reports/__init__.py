"""The imitation wing's sweep tables, read from run folders only (nothing of envs, sim or rl): the
letters (``report``), beside the thesis (``thesis_report``), the upper body's signs
(``upper_body_report``) and the residual setting (``residual_report``); their curves are drawn by
:mod:`aslexp.viz.imitation`. Each runs as ``python -m aslexp.reports.<name> FOLDER``; the imitate
job writes the tables after a sweep."""
