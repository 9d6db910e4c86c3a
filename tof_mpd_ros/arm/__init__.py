"""The robot arm: UR5e kinematics (:mod:`.ur5e`), the tool's nominal mounting (:mod:`.tool`),
reachable viewpoint plans (:mod:`.viewpoints`), and the collector's arm backends: ur_rtde on a
real UR, or the simulated UR5e (:mod:`.sessions`).

The backends run behind :class:`~tof_mpd_ros.arm.isolated.IsolatedArm`, in a child process with
timeouts, so an arm client that hangs or crashes never takes the recording down with it. Nothing
here loads the simulator; the simulator imports this package.
"""
