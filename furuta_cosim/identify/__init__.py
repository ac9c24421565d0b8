"""Identification of a real rig: measured logs in (experiment files), the plant replayed on
them and its parameters fitted to them (``furuta-cosim replay`` and ``identify``)."""
