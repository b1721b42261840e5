"""Calibration files as other tools read them (`station export`): what the formats share (imu),
ArduPilot and PX4 parameters (autopilot), Kalibr (kalibr), ROS (ros), imucal (imucal) and a C
header for firmware (c)."""
