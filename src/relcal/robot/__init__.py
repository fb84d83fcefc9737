"""Robot models, parameter layout, kinematics, IK, model files and the built-in library."""
