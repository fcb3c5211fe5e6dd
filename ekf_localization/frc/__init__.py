"""The roboRIO's side of an FRC robot, without ROS: WPILib's packed structs, NetworkTables 4 time,
and swerve module states turned into joint states (the nt_bridge node is their adapter)."""
