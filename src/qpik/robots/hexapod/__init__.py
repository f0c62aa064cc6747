"""The 6-PUS Gough–Stewart hexapod: kinematics, MJCF scene, control, scenarios, calibration."""
