"""The execution-rule study (``python -m experiments execution``): which rule for ``L_t`` beats fixed chunks
and the matched-length controls on ``MixedTraffic-v0``, chosen on development seeds and validation scenarios,
confirmed on fresh seeds and test scenarios."""
