"""The pretrained Phase-1 checkpoint of ``MixedTraffic-v0`` shipped in ``rl-trained-agents/``
(rl-baselines3-zoo's trained-agents layout): ``python -m experiments make-checkpoint``."""
