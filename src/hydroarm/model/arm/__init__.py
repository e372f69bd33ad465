"""The fixed-base arm: its description (arm files, URDF + hydrodynamics files), its true plant and
the plant's compiled path.
"""
