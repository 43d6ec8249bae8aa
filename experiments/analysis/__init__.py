"""One-off analyses of trained checkpoints and datasets on MixedTraffic-v0 (run from a checkout):
``python -m experiments.analysis.flow_fit`` (how well the flow actor fits the offline chunks) and
``python -m experiments.analysis.lane_change_timing`` (where a chunk policy schedules its lane
changes, and whether the executed prefix reaches them)."""
