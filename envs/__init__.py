"""Gymnasium environments of sb3-ua2c. Importing this package registers their ids.

Importing never needs SUMO: the simulator is imported when an environment is constructed.
"""
