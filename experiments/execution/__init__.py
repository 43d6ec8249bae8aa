"""The execution-rule study (``python -m experiments execution``): which rule for ``L_t`` beats fixed chunks and
the matched-length controls."""
