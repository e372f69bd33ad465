"""The real loop around the true plant: joint friction, the sensor and the drives."""
