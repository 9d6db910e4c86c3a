"""The simulated robotic ToF cell: scenes, UR5e arm, AMCW ToF physics, structured light."""
