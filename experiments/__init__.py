"""Research harnesses of sb3-ua2c, outside the wheel: ``fig2`` (the paper's Figure 2),
``peers`` (the head-to-head with SB3, sb3-contrib and d3rlpy), ``ogbench`` (an OGBench task) and
``common`` (what they share). Run them from a checkout as ``python -m experiments <command>``."""
