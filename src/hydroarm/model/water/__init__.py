"""The water on the wetted cylinders: Morison strips, their compiled effects, the Reynolds-
dependent drag, the current, the water's regressor and the MuJoCo cross-check.
"""
