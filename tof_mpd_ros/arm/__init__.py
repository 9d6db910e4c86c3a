"""Robot-arm backends for the collector: ur_rtde on a real UR, or the simulated UR5e.

Both run behind :class:`~tof_mpd_ros.arm.isolated.IsolatedArm`, in a child process with
timeouts, so an arm client that hangs or crashes never takes the recording down with it.
"""
