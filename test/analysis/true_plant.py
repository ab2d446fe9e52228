"""The plant of the excited test bags (conftest ``excited_bag``), shared with the fit tests."""

#: The Table 1 preset with m1 +10 %, k2 -15 % and c1 +50 % (``--plant-set``); the bag records the
#: preset, as a rig records what it was set up with.
TRUE_PLANT = {"m1": 1087.68, "m2": 748.8, "k1": 1.2e6, "k2": 1.02e6, "c1": 2940.0,
              "c2": 1960.0}
