"""ROS 2 message definitions (``ros2msg`` text) embedded so recordings need no ROS install.

Generated from the Jazzy ``.msg`` files of common_interfaces / rcl_interfaces (verbatim, comments
included), concatenated the way rosbag2 stores MCAP schemas: the top-level definition, then for
each dependency a line of 80 ``=``, a ``MSG: pkg/Type`` line and that type's text. The RIHS01
type hashes are the ones rosidl generated for Jazzy (``type_description_hash`` in metadata.yaml).
"""

# ruff: noqa: E501  (message definitions are data and are kept verbatim)

from __future__ import annotations

# Each type's own .msg text, keyed by its full name ``pkg/msg/Type``.
MSG_TEXT: dict[str, str] = {
    'sensor_msgs/msg/Image': '# This message contains an uncompressed image\n# (0, 0) is at top-left corner of image\n\nstd_msgs/Header header # Header timestamp should be acquisition time of image\n                             # Header frame_id should be optical frame of camera\n                             # origin of frame should be optical center of cameara\n                             # +x should point to the right in the image\n                             # +y should point down in the image\n                             # +z should point into to plane of the image\n                             # If the frame_id here and the frame_id of the CameraInfo\n                             # message associated with the image conflict\n                             # the behavior is undefined\n\nuint32 height                # image height, that is, number of rows\nuint32 width                 # image width, that is, number of columns\n\n# The legal values for encoding are in file include/sensor_msgs/image_encodings.hpp\n# If you want to standardize a new string format, join\n# ros-users@lists.ros.org and send an email proposing a new encoding.\n\nstring encoding       # Encoding of pixels -- channel meaning, ordering, size\n                      # taken from the list of strings in include/sensor_msgs/image_encodings.hpp\n\nuint8 is_bigendian    # is this data bigendian?\nuint32 step           # Full row length in bytes\nuint8[] data          # actual matrix data, size is (step * rows)\n',
    'std_msgs/msg/Header': '# Standard metadata for higher-level stamped data types.\n# This is generally used to communicate timestamped data\n# in a particular coordinate frame.\n\n# Two-integer timestamp that is expressed as seconds and nanoseconds.\nbuiltin_interfaces/Time stamp\n\n# Transform frame with which this data is associated.\nstring frame_id\n',
    'builtin_interfaces/msg/Time': '# This message communicates ROS Time defined here:\n# https://design.ros2.org/articles/clock_and_time.html\n\n# The seconds component, valid over all int32 values.\nint32 sec\n\n# The nanoseconds component, valid in the range [0, 1e9), to be added to the seconds component. \n# e.g.\n# The time -1.7 seconds is represented as {sec: -2, nanosec: 3e8}\n# The time 1.7 seconds is represented as {sec: 1, nanosec: 7e8}\nuint32 nanosec\n',
    'sensor_msgs/msg/CameraInfo': '# This message defines meta information for a camera. It should be in a\n# camera namespace on topic "camera_info" and accompanied by up to five\n# image topics named:\n#\n#   image_raw - raw data from the camera driver, possibly Bayer encoded\n#   image            - monochrome, distorted\n#   image_color      - color, distorted\n#   image_rect       - monochrome, rectified\n#   image_rect_color - color, rectified\n#\n# The image_pipeline contains packages (image_proc, stereo_image_proc)\n# for producing the four processed image topics from image_raw and\n# camera_info. The meaning of the camera parameters are described in\n# detail at http://www.ros.org/wiki/image_pipeline/CameraInfo.\n#\n# The image_geometry package provides a user-friendly interface to\n# common operations using this meta information. If you want to, e.g.,\n# project a 3d point into image coordinates, we strongly recommend\n# using image_geometry.\n#\n# If the camera is uncalibrated, the matrices D, K, R, P should be left\n# zeroed out. In particular, clients may assume that K[0] == 0.0\n# indicates an uncalibrated camera.\n\n#######################################################################\n#                     Image acquisition info                          #\n#######################################################################\n\n# Time of image acquisition, camera coordinate frame ID\nstd_msgs/Header header # Header timestamp should be acquisition time of image\n                             # Header frame_id should be optical frame of camera\n                             # origin of frame should be optical center of camera\n                             # +x should point to the right in the image\n                             # +y should point down in the image\n                             # +z should point into the plane of the image\n\n\n#######################################################################\n#                      Calibration Parameters                         #\n#######################################################################\n# These are fixed during camera calibration. Their values will be the #\n# same in all messages until the camera is recalibrated. Note that    #\n# self-calibrating systems may "recalibrate" frequently.              #\n#                                                                     #\n# The internal parameters can be used to warp a raw (distorted) image #\n# to:                                                                 #\n#   1. An undistorted image (requires D and K)                        #\n#   2. A rectified image (requires D, K, R)                           #\n# The projection matrix P projects 3D points into the rectified image.#\n#######################################################################\n\n# The image dimensions with which the camera was calibrated.\n# Normally this will be the full camera resolution in pixels.\nuint32 height\nuint32 width\n\n# The distortion model used. Supported models are listed in\n# sensor_msgs/distortion_models.hpp. For most cameras, "plumb_bob" - a\n# simple model of radial and tangential distortion - is sufficent.\nstring distortion_model\n\n# The distortion parameters, size depending on the distortion model.\n# For "plumb_bob", the 5 parameters are: (k1, k2, t1, t2, k3).\nfloat64[] d\n\n# Intrinsic camera matrix for the raw (distorted) images.\n#     [fx  0 cx]\n# K = [ 0 fy cy]\n#     [ 0  0  1]\n# Projects 3D points in the camera coordinate frame to 2D pixel\n# coordinates using the focal lengths (fx, fy) and principal point\n# (cx, cy).\nfloat64[9]  k # 3x3 row-major matrix\n\n# Rectification matrix (stereo cameras only)\n# A rotation matrix aligning the camera coordinate system to the ideal\n# stereo image plane so that epipolar lines in both stereo images are\n# parallel.\nfloat64[9]  r # 3x3 row-major matrix\n\n# Projection/camera matrix\n#     [fx\'  0  cx\' Tx]\n# P = [ 0  fy\' cy\' Ty]\n#     [ 0   0   1   0]\n# By convention, this matrix specifies the intrinsic (camera) matrix\n#  of the processed (rectified) image. That is, the left 3x3 portion\n#  is the normal camera intrinsic matrix for the rectified image.\n# It projects 3D points in the camera coordinate frame to 2D pixel\n#  coordinates using the focal lengths (fx\', fy\') and principal point\n#  (cx\', cy\') - these may differ from the values in K.\n# For monocular cameras, Tx = Ty = 0. Normally, monocular cameras will\n#  also have R = the identity and P[1:3,1:3] = K.\n# For a stereo pair, the fourth column [Tx Ty 0]\' is related to the\n#  position of the optical center of the second camera in the first\n#  camera\'s frame. We assume Tz = 0 so both cameras are in the same\n#  stereo image plane. The first camera always has Tx = Ty = 0. For\n#  the right (second) camera of a horizontal stereo pair, Ty = 0 and\n#  Tx = -fx\' * B, where B is the baseline between the cameras.\n# Given a 3D point [X Y Z]\', the projection (x, y) of the point onto\n#  the rectified image is given by:\n#  [u v w]\' = P * [X Y Z 1]\'\n#         x = u / w\n#         y = v / w\n#  This holds for both images of a stereo pair.\nfloat64[12] p # 3x4 row-major matrix\n\n\n#######################################################################\n#                      Operational Parameters                         #\n#######################################################################\n# These define the image region actually captured by the camera       #\n# driver. Although they affect the geometry of the output image, they #\n# may be changed freely without recalibrating the camera.             #\n#######################################################################\n\n# Binning refers here to any camera setting which combines rectangular\n#  neighborhoods of pixels into larger "super-pixels." It reduces the\n#  resolution of the output image to\n#  (width / binning_x) x (height / binning_y).\n# The default values binning_x = binning_y = 0 is considered the same\n#  as binning_x = binning_y = 1 (no subsampling).\nuint32 binning_x\nuint32 binning_y\n\n# Region of interest (subwindow of full camera resolution), given in\n#  full resolution (unbinned) image coordinates. A particular ROI\n#  always denotes the same window of pixels on the camera sensor,\n#  regardless of binning settings.\n# The default setting of roi (all values 0) is considered the same as\n#  full resolution (roi.width = width, roi.height = height).\nRegionOfInterest roi\n',
    'sensor_msgs/msg/RegionOfInterest': '# This message is used to specify a region of interest within an image.\n#\n# When used to specify the ROI setting of the camera when the image was\n# taken, the height and width fields should either match the height and\n# width fields for the associated image; or height = width = 0\n# indicates that the full resolution image was captured.\n\nuint32 x_offset  # Leftmost pixel of the ROI\n                 # (0 if the ROI includes the left edge of the image)\nuint32 y_offset  # Topmost pixel of the ROI\n                 # (0 if the ROI includes the top edge of the image)\nuint32 height    # Height of ROI\nuint32 width     # Width of ROI\n\n# True if a distinct rectified ROI should be calculated from the "raw"\n# ROI in this message. Typically this should be False if the full image\n# is captured (ROI not used), and True if a subwindow is captured (ROI\n# used).\nbool do_rectify\n',
    'sensor_msgs/msg/PointCloud2': '# This message holds a collection of N-dimensional points, which may\n# contain additional information such as normals, intensity, etc. The\n# point data is stored as a binary blob, its layout described by the\n# contents of the "fields" array.\n#\n# The point cloud data may be organized 2d (image-like) or 1d (unordered).\n# Point clouds organized as 2d images may be produced by camera depth sensors\n# such as stereo or time-of-flight.\n\n# Time of sensor data acquisition, and the coordinate frame ID (for 3d points).\nstd_msgs/Header header\n\n# 2D structure of the point cloud. If the cloud is unordered, height is\n# 1 and width is the length of the point cloud.\nuint32 height\nuint32 width\n\n# Describes the channels and their layout in the binary data blob.\nPointField[] fields\n\nbool    is_bigendian # Is this data bigendian?\nuint32  point_step   # Length of a point in bytes\nuint32  row_step     # Length of a row in bytes\nuint8[] data         # Actual point data, size is (row_step*height)\n\nbool is_dense        # True if there are no invalid points\n',
    'sensor_msgs/msg/PointField': '# This message holds the description of one point entry in the\n# PointCloud2 message format.\nuint8 INT8    = 1\nuint8 UINT8   = 2\nuint8 INT16   = 3\nuint8 UINT16  = 4\nuint8 INT32   = 5\nuint8 UINT32  = 6\nuint8 FLOAT32 = 7\nuint8 FLOAT64 = 8\n\n# Common PointField names are x, y, z, intensity, rgb, rgba\nstring name      # Name of field\nuint32 offset    # Offset from start of point struct\nuint8  datatype  # Datatype enumeration, see above\nuint32 count     # How many elements in the field\n',
    'geometry_msgs/msg/PoseStamped': '# A Pose with reference coordinate frame and timestamp\n\nstd_msgs/Header header\nPose pose\n',
    'geometry_msgs/msg/Pose': '# A representation of pose in free space, composed of position and orientation.\n\nPoint position\nQuaternion orientation\n',
    'geometry_msgs/msg/Point': '# This contains the position of a point in free space\nfloat64 x\nfloat64 y\nfloat64 z\n',
    'geometry_msgs/msg/Quaternion': '# This represents an orientation in free space in quaternion form.\n\nfloat64 x 0\nfloat64 y 0\nfloat64 z 0\nfloat64 w 1\n',
    'geometry_msgs/msg/TransformStamped': '# This expresses a transform from coordinate frame header.frame_id\n# to the coordinate frame child_frame_id at the time of header.stamp\n#\n# This message is mostly used by the\n# <a href="https://docs.ros.org/en/rolling/p/tf2/">tf2</a> package.\n# See its documentation for more information.\n#\n# The child_frame_id is necessary in addition to the frame_id\n# in the Header to communicate the full reference for the transform\n# in a self contained message.\n\n# The frame id in the header is used as the reference frame of this transform.\nstd_msgs/Header header\n\n# The frame id of the child frame to which this transform points.\nstring child_frame_id\n\n# Translation and rotation in 3-dimensions of child_frame_id from header.frame_id.\nTransform transform\n',
    'geometry_msgs/msg/Transform': '# This represents the transform between two coordinate frames in free space.\n\nVector3 translation\nQuaternion rotation\n',
    'geometry_msgs/msg/Vector3': '# This represents a vector in free space.\n\n# This is semantically different than a point.\n# A vector is always anchored at the origin.\n# When a transform is applied to a vector, only the rotational component is applied.\n\nfloat64 x\nfloat64 y\nfloat64 z\n',
    'std_msgs/msg/Float64MultiArray': '# This was originally provided as an example message.\n# It is deprecated as of Foxy\n# It is recommended to create your own semantically meaningful message.\n# However if you would like to continue using this please use the equivalent in example_msgs.\n\n# Please look at the MultiArrayLayout message definition for\n# documentation on all multiarrays.\n\nMultiArrayLayout  layout        # specification of data layout\nfloat64[]         data          # array of data\n',
    'std_msgs/msg/MultiArrayLayout': '# This was originally provided as an example message.\n# It is deprecated as of Foxy\n# It is recommended to create your own semantically meaningful message.\n# However if you would like to continue using this please use the equivalent in example_msgs.\n\n# The multiarray declares a generic multi-dimensional array of a\n# particular data type.  Dimensions are ordered from outer most\n# to inner most.\n#\n# Accessors should ALWAYS be written in terms of dimension stride\n# and specified outer-most dimension first.\n#\n# multiarray(i,j,k) = data[data_offset + dim_stride[1]*i + dim_stride[2]*j + k]\n#\n# A standard, 3-channel 640x480 image with interleaved color channels\n# would be specified as:\n#\n# dim[0].label  = "height"\n# dim[0].size   = 480\n# dim[0].stride = 3*640*480 = 921600  (note dim[0] stride is just size of image)\n# dim[1].label  = "width"\n# dim[1].size   = 640\n# dim[1].stride = 3*640 = 1920\n# dim[2].label  = "channel"\n# dim[2].size   = 3\n# dim[2].stride = 3\n#\n# multiarray(i,j,k) refers to the ith row, jth column, and kth channel.\n\nMultiArrayDimension[] dim # Array of dimension properties\nuint32 data_offset        # padding bytes at front of data\n',
    'std_msgs/msg/MultiArrayDimension': '# This was originally provided as an example message.\n# It is deprecated as of Foxy\n# It is recommended to create your own semantically meaningful message.\n# However if you would like to continue using this please use the equivalent in example_msgs.\n\nstring label   # label of given dimension\nuint32 size    # size of given dimension (in type units)\nuint32 stride  # stride of given dimension\n',
}

# Direct and indirect dependencies of each type, in the order rosbag2 appends them.
DEPENDENCIES: dict[str, tuple[str, ...]] = {
    'sensor_msgs/msg/Image': ('std_msgs/msg/Header', 'builtin_interfaces/msg/Time'),
    'std_msgs/msg/Header': ('builtin_interfaces/msg/Time',),
    'builtin_interfaces/msg/Time': (),
    'sensor_msgs/msg/CameraInfo': ('std_msgs/msg/Header', 'builtin_interfaces/msg/Time', 'sensor_msgs/msg/RegionOfInterest'),
    'sensor_msgs/msg/RegionOfInterest': (),
    'sensor_msgs/msg/PointCloud2': ('std_msgs/msg/Header', 'builtin_interfaces/msg/Time', 'sensor_msgs/msg/PointField'),
    'sensor_msgs/msg/PointField': (),
    'geometry_msgs/msg/PoseStamped': ('std_msgs/msg/Header', 'builtin_interfaces/msg/Time', 'geometry_msgs/msg/Pose', 'geometry_msgs/msg/Point', 'geometry_msgs/msg/Quaternion'),
    'geometry_msgs/msg/Pose': ('geometry_msgs/msg/Point', 'geometry_msgs/msg/Quaternion'),
    'geometry_msgs/msg/Point': (),
    'geometry_msgs/msg/Quaternion': (),
    'geometry_msgs/msg/TransformStamped': ('std_msgs/msg/Header', 'builtin_interfaces/msg/Time', 'geometry_msgs/msg/Transform', 'geometry_msgs/msg/Vector3', 'geometry_msgs/msg/Quaternion'),
    'geometry_msgs/msg/Transform': ('geometry_msgs/msg/Vector3', 'geometry_msgs/msg/Quaternion'),
    'geometry_msgs/msg/Vector3': (),
    'std_msgs/msg/Float64MultiArray': ('std_msgs/msg/MultiArrayLayout', 'std_msgs/msg/MultiArrayDimension'),
    'std_msgs/msg/MultiArrayLayout': ('std_msgs/msg/MultiArrayDimension',),
    'std_msgs/msg/MultiArrayDimension': (),
}

# RIHS01 type description hashes (rosidl, Jazzy).
TYPE_HASHES: dict[str, str] = {
    'sensor_msgs/msg/Image': 'RIHS01_d31d41a9a4c4bc8eae9be757b0beed306564f7526c88ea6a4588fb9582527d47',
    'std_msgs/msg/Header': 'RIHS01_f49fb3ae2cf070f793645ff749683ac6b06203e41c891e17701b1cb597ce6a01',
    'builtin_interfaces/msg/Time': 'RIHS01_b106235e25a4c5ed35098aa0a61a3ee9c9b18d197f398b0e4206cea9acf9c197',
    'sensor_msgs/msg/CameraInfo': 'RIHS01_b3dfd68ff46c9d56c80fd3bd4ed22c7a4ddce8c8348f2f59c299e73118e7e275',
    'sensor_msgs/msg/RegionOfInterest': 'RIHS01_ad16bcba5f9131dcdba6fbded19f726f5440e3c513b4fb586dd3027eeed8abb1',
    'sensor_msgs/msg/PointCloud2': 'RIHS01_9198cabf7da3796ae6fe19c4cb3bdd3525492988c70522628af5daa124bae2b5',
    'sensor_msgs/msg/PointField': 'RIHS01_5c6a4750728c2bcfbbf7037225b20b02d4429634732146b742dee1726637ef01',
    'geometry_msgs/msg/PoseStamped': 'RIHS01_10f3786d7d40fd2b54367835614bff85d4ad3b5dab62bf8bca0cc232d73b4cd8',
    'geometry_msgs/msg/Pose': 'RIHS01_d501954e9476cea2996984e812054b68026ae0bfae789d9a10b23daf35cc90fa',
    'geometry_msgs/msg/Point': 'RIHS01_6963084842a9b04494d6b2941d11444708d892da2f4b09843b9c43f42a7f6881',
    'geometry_msgs/msg/Quaternion': 'RIHS01_8a765f66778c8ff7c8ab94afcc590a2ed5325a1d9a076ffff38fbce36f458684',
    'geometry_msgs/msg/TransformStamped': 'RIHS01_0a241f87d04668d94099cbb5ba11691d5ad32c2f29682e4eb5653424bd275206',
    'geometry_msgs/msg/Transform': 'RIHS01_beb83fbe698636351461f6f35d1abb20010c43d55374d81bd041f1ba2581fddc',
    'geometry_msgs/msg/Vector3': 'RIHS01_cc12fe83e4c02719f1ce8070bfd14aecd40f75a96696a67a2a1f37f7dbb0765d',
    'std_msgs/msg/Float64MultiArray': 'RIHS01_1025ddc6b9552d191f89ef1a8d2f60f3d373e28b283d8891ddcc974e8c55397f',
    'std_msgs/msg/MultiArrayLayout': 'RIHS01_4c66e6f78e740ac103a94cf63259f968e48c617e7699e829b63c21a5cb50dac6',
    'std_msgs/msg/MultiArrayDimension': 'RIHS01_5e773a60a4c7fc8a54985f307c7837aa2994252a126c301957a24e31282c9cbe',
}

SEPARATOR = "=" * 80

# The message types this package writes.
IMAGE = "sensor_msgs/msg/Image"
CAMERA_INFO = "sensor_msgs/msg/CameraInfo"
POINT_CLOUD2 = "sensor_msgs/msg/PointCloud2"
POSE_STAMPED = "geometry_msgs/msg/PoseStamped"
TRANSFORM_STAMPED = "geometry_msgs/msg/TransformStamped"
FLOAT64_MULTI_ARRAY = "std_msgs/msg/Float64MultiArray"


def _short(msgtype: str) -> str:
    """``pkg/msg/Type`` -> ``pkg/Type``, the spelling of ``MSG:`` lines."""
    pkg, _, name = msgtype.split("/")
    return f"{pkg}/{name}"


def schema_text(msgtype: str) -> str:
    """Full ``ros2msg`` schema of ``msgtype`` with all its dependencies, as rosbag2 stores it.

    Args:
        msgtype: full type name, e.g. ``"sensor_msgs/msg/Image"``.

    Raises:
        KeyError: the type is not embedded here.
    """
    parts = [MSG_TEXT[msgtype].rstrip("\n") + "\n"]
    for dep in DEPENDENCIES[msgtype]:
        parts.append(f"{SEPARATOR}\nMSG: {_short(dep)}\n{MSG_TEXT[dep].rstrip(chr(10))}\n")
    return "".join(parts)


def known_types() -> tuple[str, ...]:
    """Every message type whose definition is embedded."""
    return tuple(MSG_TEXT)
