"""The vehicle and the floating vehicle-manipulator system: the vehicle file, the system's
Pinocchio model and state layout, its true plant, its compiled path and the prescribed-motion
plant of the replay.
"""
