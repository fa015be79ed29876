"""Machine kinematics and (with the bridge) time parameterisation."""
