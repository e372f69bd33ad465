"""The numerics every system shares: RK4 integration, the compiled tree passes, fixed-order algebra
and the nominal (dry) model the controllers know.
"""
