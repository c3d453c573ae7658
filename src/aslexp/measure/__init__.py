"""Measurements that simulate and learn nothing: the numbers a result is compared with.

A room of its own so that reports only read run folders (:mod:`aslexp.reports` imports nothing of
``envs``, ``sim`` or ``rl``). What a result needs is measured when its run runs (the imitate job
calls :mod:`aslexp.measure.residual`), or by a command of its own that writes its folder:

* :mod:`~aslexp.measure.residual`: the residual setting's comparison rows (the controller alone, on a
  pinned base, a smoothed reference, constant random corrections, where the root drifts);
* :mod:`~aslexp.measure.engine_agreement`: the same controllers on both engines (docs/engines.md);
* :mod:`~aslexp.measure.noise_cost`: what exploration noise alone costs a run's controller.
"""
