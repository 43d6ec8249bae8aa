"""Small UA2C settings shared by the algorithm tests (seconds per test on one core)."""

#: tiny networks
TINY = dict(net_arch=[32, 32], critic_embed_dim=16, critic_ff_dim=32)
#: tiny networks, short warm-up, few candidates
FAST = dict(
    policy_kwargs=TINY,
    learning_starts=50,
    batch_size=16,
    buffer_size=1000,
    flow_steps=3,
    n_candidates=4,
    n_target_candidates=2,
)
