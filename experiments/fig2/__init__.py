"""The paper's Figure 2 on ``MixedTraffic-v0`` over several seeds: ``python -m experiments fig2``."""
