"""The calibration model: units, Earth, kinematics of the table, motion profiles, the IMU model,
observations, closed forms, the result file and the coefficient families."""
