"""One-off analyses of trained checkpoints and datasets on MixedTraffic-v0 (run from a checkout):
``python -m experiments flow-fit`` (how well the flow actor fits the offline chunks),
``python -m experiments lane-change-timing`` (where a chunk policy schedules its lane
changes, and whether the executed prefix reaches them), and ``python -m experiments paired``
(the paired per-seed difference of any two arms, within one run or across runs)."""
