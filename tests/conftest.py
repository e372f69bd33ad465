"""Shared test settings: hypothesis draws the same examples on every run (CI must not flake)."""

from hypothesis import settings

settings.register_profile("hydroarm", derandomize=True, database=None)
settings.load_profile("hydroarm")
