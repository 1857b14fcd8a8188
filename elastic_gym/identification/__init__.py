"""Identification of the elastic-joint model from a sensor log (motor encoders, motor
torques, link accelerometers)."""
