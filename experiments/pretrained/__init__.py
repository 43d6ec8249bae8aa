"""The pretrained checkpoint of ``rl-trained-agents/``: ``python -m experiments make-checkpoint``."""
