"""Named configurations of UA2C: plain dicts of constructor arguments (with a ``policy_kwargs`` dict),
so that a configuration is one switch away: ``UA2C("MlpPolicy", env, **preset("paper"))``.

A preset sets the algorithm's variant: the actor objective, the sampling of candidates and targets,
the execution rule, the critics and the update schedule. It leaves out what belongs to the problem
(``chunk_size``, ``history_len``, ``discrete_action_dims``, the replay sizes) and SB3's optimisation
settings (``learning_rate``, ``batch_size``, ``gamma``, ``tau``): pass those next to it. The rl-zoo3
form of a preset is a YAML file of its own, ``zoo_configs/ua2c_<name>.yml`` (rl-zoo3 keys map one to
one to constructor arguments; a test keeps the two equal).
"""

from __future__ import annotations

import copy
from typing import Any

#: The paper as written ("UA2C: Uncertainty-Aware Adaptive Action Chunking for Offline-to-Online
#: Decision-Making in Mixed Traffic"). The constructors' defaults of this release differ from it in six
#: values, chosen on validation seeds and scenarios of ``MixedTraffic-v0`` (docs/algorithm.md,
#: "Defaults and the paper preset"): ``gradient_steps`` 1 (one update per env step), ``q_weight`` 0.3,
#: ``flow_steps`` 5, ``exploration`` "softmax", ``policy_kwargs`` ``net_arch`` [256, 256] and ``n_elite``
#: 8. The preset:
#:
#: - ``q_weight`` 1.0, ``normalize_q`` True: Eq. 2's value term ``λ Q(x̂1)``, divided by the batch mean
#:   ``|Q|`` (TD3+BC's normalisation, so that λ does not depend on the reward scale)
#: - ``smooth_weight`` 0.0, ``past_action_dropout`` 0.0: Eq. 2 alone (neither term is in the paper)
#: - ``flow_steps`` 10, ``n_candidates`` 32: §3.2's sampler when acting (N Euler steps, S candidates)
#: - ``target_flow_steps`` 2, ``n_target_candidates`` 2: the cheaper sampler of the targets of Eq. 4 / 8
#: - ``execution_rule`` "threshold", ``entropy_threshold`` 0.0: Eq. 7 with one δ in nats
#: - ``exploration`` "plan": rollouts act as ``predict`` (with ``n_elite`` 1, the best candidate)
#: - ``train_freq`` 1, ``gradient_steps`` -1: one update per chunk sampled (per replanning)
#: - ``offline_ratio`` 0.5, ``online_targets`` "auto": half of each batch offline (§3.3), online samples
#:   with the executed prefix's target of Eq. 8 once offline episodes are stored
#: - ``policy_kwargs``: ``actor_type`` "flow" (the velocity field of Eq. 2 acts and is trained by the
#:   value term), ``actor_past_actions`` True (``h_t`` holds observations and past actions, §3.1),
#:   ``n_elite`` 1 (the best candidate by ``min_j Q_j``), ``net_arch`` [128, 128] (the velocity field's
#:   MLP), ``critic_arch`` "transformer" with ``critic_kwargs`` ``embed_dim`` 32, ``n_layers`` 1,
#:   ``n_heads`` 1, ``ff_dim`` 64 (the per-token Transformer critic of §3.1) and ``n_critics`` 2 (the
#:   twin critics of Eq. 3, clipped double Q)
#:
#: Where a value is also this release's default, its line says so (``# same as default:``): the preset
#: states the paper's value so that it stays the paper's when a default changes.
PAPER: dict[str, Any] = {
    "q_weight": 1.0,
    "normalize_q": True,  # same as default: the paper's
    "smooth_weight": 0.0,  # same as default: the paper's
    "past_action_dropout": 0.0,  # same as default: the paper's
    "flow_steps": 10,
    "n_candidates": 32,  # same as default: the paper's
    "target_flow_steps": 2,  # same as default: the paper's
    "n_target_candidates": 2,  # same as default: the paper's
    "execution_rule": "threshold",  # same as default: the paper's
    "entropy_threshold": 0.0,  # same as default: the paper's
    "exploration": "plan",
    "train_freq": 1,  # same as default: the paper's
    "gradient_steps": -1,
    "offline_ratio": 0.5,  # same as default: the paper's
    "online_targets": "auto",  # same as default: the paper's
    "policy_kwargs": {
        "actor_type": "flow",  # same as default: the paper's
        "actor_past_actions": True,  # same as default: the paper's
        "n_elite": 1,
        "net_arch": [128, 128],
        "critic_arch": "transformer",  # same as default: the paper's
        "critic_kwargs": {"embed_dim": 32, "n_layers": 1, "n_heads": 1, "ff_dim": 64},  # same as default: the paper's
        "n_critics": 2,  # same as default: the paper's
    },
}

#: the presets by name
PRESETS: dict[str, dict[str, Any]] = {"paper": PAPER}


def preset(name: str) -> dict[str, Any]:
    """
    A copy of a named configuration, to pass to the constructor: ``UA2C("MlpPolicy", env, **preset("paper"))``
    (add to its ``policy_kwargs`` before passing it, e.g. ``kwargs["policy_kwargs"]["torch_compile"] = True``).

    :param name: one of :data:`PRESETS` (``"paper"``: :data:`PAPER`)
    :return: a deep copy (changing it leaves the preset as it is)
    """
    if name not in PRESETS:
        raise ValueError(f"preset name must be one of {sorted(PRESETS)}, got {name!r}")
    return copy.deepcopy(PRESETS[name])


__all__ = ["PAPER", "PRESETS", "preset"]
