"""A stand-in for Quanser's Python API (the ``quanser`` package of the Quanser SDK) in tests."""
