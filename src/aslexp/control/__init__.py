"""Controllers that act without learning and need the simulation itself: sampling-based
model-predictive control over an engine that batches (:mod:`aslexp.control.mpc`), the empirical
ceiling every learned imitation result is read against."""
