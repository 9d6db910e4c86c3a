"""Topic names of the cell's devices, shared by ``sim_cell`` (publishes) and ``collector``
(subscribes) so that the two pair with no configuration.

Relative names, like image_pipeline's: in the root namespace they resolve to ``/tof/...``,
``/sl/...`` and ``/arm/...``; users move them with ``-r __ns:=...`` or ``-r from:=to``.
"""

from __future__ import annotations

#: key -> relative topic name. The ToF camera's CameraInfo sits next to its depth image.
CELL_TOPICS = {
    "depth": "tof/depth/image_raw",
    "amplitude": "tof/amplitude/image_raw",
    "info": "tof/depth/camera_info",
    "reference": "sl/depth/image_raw",
    "sl_image": "sl/image_raw",
    "sl_info": "sl/camera_info",
    "tcp_pose": "arm/tcp_pose",
}

#: The topic parameters these names replaced (issue 14) -> the name to remap instead.
RETIRED_TOPIC_PARAMETERS = {
    "depth_topic": CELL_TOPICS["depth"],
    "amplitude_topic": CELL_TOPICS["amplitude"],
    "camera_info_topic": CELL_TOPICS["info"],
    "reference_topic": CELL_TOPICS["reference"],
    "sl_image_topic": CELL_TOPICS["sl_image"],
    "sl_camera_info_topic": CELL_TOPICS["sl_info"],
    "tcp_pose_topic": CELL_TOPICS["tcp_pose"],
}
